"""Command-line values that make no sense are argparse errors; a replay start past the log and an echo
that hears nothing say so."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from palpate.argtypes import (
    non_negative_float,
    non_negative_int,
    positive_float,
    positive_int,
    positive_scale,
)
from palpate.cli import build_parser, main
from tests.unit.record.synthetic import canonical_log, write_log


@pytest.mark.parametrize(
    "argv",
    [
        ["replay", "x.mcap", "--rate", "-1"],
        ["replay", "x.mcap", "--rate", "nan"],
        ["replay", "x.mcap", "--rate", "inf"],
        ["replay", "x.mcap", "--start", "-2"],
        ["replay", "x.mcap", "--wait-timeout", "-1"],
        ["replay", "x.mcap", "--subscribers", "-1"],
        ["record", "-o", "x.mcap", "--chunk-size", "0"],
        ["record", "-o", "x.mcap", "--chunk-ticks", "-1"],
        ["topic", "hz", "clock", "--window", "0"],
        ["topic", "hz", "clock", "--duration", "-1"],
        ["topic", "echo", "clock", "--timeout", "nan"],
        ["topic", "echo", "clock", "-n", "-3"],
        ["eval", "explore", "--workers", "-1"],
        ["view", "--duration", "-1"],
        ["bench", "fuzz", "--frames", "-5"],  # ran 0 frames and passed
        ["bench", "fuzz", "--frames", "0"],  # ran the default 1000
        ["bench", "bus", "--rounds", "0"],
        ["bench", "gpis", "--repeats", "0"],
        ["bench", "gpis", "--seed", "-1"],
        ["bench", "sim", "--duration", "-1"],
        ["bench", "contacts", "--touches", "0"],
        ["bench", "contacts", "--objects", ""],
        ["eval", "explore", "--objects", ""],  # searched the working directory for meshes
        ["sweep", "explore", "--objects", " "],
        ["eval", "explore", "--out", ""],  # wrote its tables and plots into the working directory
        ["launch", "x.yaml", "--record", ""],
        ["record", "-o", ""],
    ],
)
def test_nonsense_values_are_argparse_errors(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        build_parser().parse_args(argv)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "argument" in err and argv[-2] in err and repr(argv[-1]) in err, err


def test_sensible_values_pass() -> None:
    args = build_parser().parse_args(["replay", "x.mcap", "--rate", "0", "--start", "1.5", "--wait-timeout", "0"])
    assert (args.rate, args.start, args.wait_timeout) == (0.0, 1.5, 0.0)


def test_replay_refuses_a_start_past_the_end_of_the_log(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = tmp_path / "run.mcap"
    write_log(log, canonical_log(3))
    assert main(["replay", str(log), "--start", "5", "--bus", str(tmp_path / "bus")]) == 2
    assert "--start 5 s is past the end of" in capsys.readouterr().err


def test_topic_echo_says_when_nothing_arrived(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["topic", "echo", "nope", "--timeout", "0.2", "--bus", str(tmp_path)]) == 1
    assert "nothing arrived on 'nope' in 0.2 s" in capsys.readouterr().err


def test_the_bounds_of_the_argument_types() -> None:
    assert (positive_int("1"), non_negative_int("0")) == (1, 0)
    assert (non_negative_float("0"), positive_float("1e-300"), positive_scale("0.001")) == (0.0, 1e-300, 0.001)
    for parse, text, refusal in [
        (positive_int, "0", "'0' is not a positive integer"),
        (non_negative_int, "-1", "'-1' is not an integer >= 0"),
        (positive_float, "0", "'0' is not a finite number > 0"),
        (positive_float, "-0.0", "'-0.0' is not a finite number > 0"),
        (positive_scale, "0", "expected a finite number > 0 (0.001: millimetres), got '0'"),
        (non_negative_float, "-1e-300", "'-1e-300' is not a finite number >= 0"),
    ]:
        with pytest.raises(argparse.ArgumentTypeError, match=rf"^{re.escape(refusal)}$"):
            parse(text)
