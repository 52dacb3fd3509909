"""Command-line values that make no sense are argparse errors; a replay start past the log and an echo
that hears nothing say so."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from palpate.argtypes import (
    bounded_positive_int,
    json_object,
    json_string_map,
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
        ["topic", "hz", "clock", "--window", str(2**70)],  # OverflowError making the rate's buffer
        ["record", "-o", "x.mcap", "--about", "[1]"],  # AttributeError: 'list' object has no attribute 'items'
        ["record", "-o", "x.mcap", "--curve-servers", '"s"'],  # ValueError from dict()
        ["record", "-o", "x.mcap", "--curve-servers", '{"tcp://h:1": 1}'],
        ["bench", "contacts", "--touches", str(2**70)],  # ValueError sampling the touches
    ],
)
def test_nonsense_values_are_argparse_errors(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        build_parser().parse_args(argv)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "argument" in err and argv[-2] in err and repr(argv[-1]) in err, err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["demo", "--out", "{file}"], "palpate demo: --out "),  # FileExistsError
        (["demo", "--out", "{file}/x"], "palpate demo: --out "),  # NotADirectoryError
        (["demo", "--out", "d/" * 1500], "palpate demo: --out "),  # RecursionError in pathlib's mkdir
        (["docs", "messages", "-o", "{dir}"], "palpate docs messages: cannot write"),  # IsADirectoryError
        (["docs", "messages", "-o", "{file}/x.md"], "palpate docs messages: cannot write"),  # FileExistsError
        (["docs", "messages", "--check", "-o", "{dir}"], "palpate docs messages: cannot read"),
        (["keys", "-o", "{dir}", "--force"], "palpate keys: cannot write"),  # IsADirectoryError
        (["keys", "-o", "{file}/x.key"], "palpate keys: cannot write"),  # FileExistsError from mkdir
        (["keys", "-o", "/dev/null", "--force"], "wrote /dev/null"),  # read the key back: JSONDecodeError
        (["keys", "-o", "k.key", "--server-public", "~" * 40], "must be a 40-character z85"),  # failed at connect
        (["record", "-o", "{file}/x.mcap", "--bus", "{dir}"], "palpate record: -o "),  # FileExistsError
        (["record", "-o", "a" * 300, "--bus", "{dir}"], "palpate record: -o "),  # OSError: name too long
        (["replay", "{log}", "--bus", "{file}"], "is not a directory"),  # FileExistsError
        (["replay", "{log}", "--start", "1e308", "--bus", "{dir}"], "past the end of"),  # OverflowError
        (["topic", "list", "--bus", "a" * 300], "cannot read bus directory"),  # OSError: name too long
        (["node", "list", "--bus", "a" * 300], "cannot read bus directory"),
        (["bag", "recover", "{log}", "-o", "a" * 300, "--force"], "palpate bag: -o "),  # OSError: name too long
        (["bag", "recover", "/", "--force"], "is a directory, not a log"),  # ValueError: Path('/').with_name
        (["bag", "filter", "a" * 300, "-o", "x.mcap", "--topics", "t"], "palpate bag: "),  # OSError in is_file
        (["topic", "echo", "clock", "--bus", "{dir}", "--curve-keys", "/dev/zero"], "not a key file"),  # MemoryError
    ],
)
def test_command_lines_found_by_the_fuzzer_give_a_palpate_error(
    argv: list[str], message: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "file").write_bytes(b"not a folder")
    (tmp_path / "dir").mkdir()
    write_log(tmp_path / "run.mcap", canonical_log(3))
    places = {"file": "file", "dir": "dir", "log": "run.mcap"}
    code = main([item.format(**places) for item in argv])
    out, err = capsys.readouterr()
    assert code == (0 if message.startswith("wrote") else 2), err
    assert message in out + err


def test_docs_check_reads_no_more_than_the_reference(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["docs", "messages", "--check", "-o", "/dev/zero"]) == 1  # read /dev/zero to the end: MemoryError
    assert "out of date" in capsys.readouterr().out


def test_json_and_bounded_argument_types() -> None:
    assert (json_object('{"a": [1]}'), json_string_map('{"a": "b"}')) == ({"a": [1]}, {"a": "b"})
    assert bounded_positive_int(5)("5") == 5
    for parse, text, refusal in [
        (json_object, "[1]", "'[1]' is not a JSON object {...}"),
        (json_object, "{", "'{' is not JSON; give an object {...}"),
        (json_object, "[" * 100_000, f"{'[' * 100!r}...{'[' * 100!r} is not JSON; give an object {{...}}"),
        (json_string_map, '{"a": 1}', "'{\"a\": 1}': every value must be a string"),
        (bounded_positive_int(5), "6", "'6' is more than 5"),
        (bounded_positive_int(5), "0", "'0' is not a positive integer"),
    ]:
        with pytest.raises(argparse.ArgumentTypeError, match=rf"^{re.escape(refusal)}$"):
            parse(text)


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
