"""`palpate bench gpis`: the smallest run end to end, the goal check and the CLI errors."""

from __future__ import annotations

import argparse
import json
import math
from typing import Any

import numpy as np
import pytest

from palpate.bench import gpis as bench_gpis
from palpate.errors import BenchmarkError


def test_smallest_run_prints_a_row_per_grid_and_json_last(capsys: Any) -> None:
    args = argparse.Namespace(
        quick=True, json=True, contacts=[12], resolutions=[10.0, 20.0], repeats=2, seed=1, shapes=None
    )
    assert bench_gpis.main(args) == 0  # no row at 200 contacts: no goal to miss
    out = capsys.readouterr().out.strip().splitlines()
    last = json.loads(out[-1])
    assert last["goal"] is None and last["pass"] and last["repeats"] == 2 and last["quick"]
    assert any(line.startswith("goal check: not run") for line in out)
    rows = last["rows"]
    assert [(r["n_contacts"], r["resolution_m"]) for r in rows] == [(12, 0.01), (12, 0.02)]
    for r in rows:
        for name in (*bench_gpis.TIMED, "total", "total_without_variance"):
            for key in (f"{name}_ms", f"cpu_{name}_ms"):
                assert math.isfinite(r[key]) and r[key] > 0, key
        assert r["cpu_total_ms"] == pytest.approx(r["cpu_add_contact_ms"] + r["cpu_local_surface_ms"])
        assert r["n_vertices"] > 0 and r["n_faces"] > 0
    assert rows[0]["n_vertices"] > rows[1]["n_vertices"]  # a finer grid gives more vertices
    table_rows = [line.split() for line in out if line.split() and line.split()[0] == "12"]
    assert [float(cells[1]) for cells in table_rows] == [10.0, 20.0]


def test_one_step_at_the_default_patch_reports_positive_timings() -> None:
    (result,) = bench_gpis.benchmark_steps(30, resolutions_m=[0.01], repeats=2)
    for key in ("add_contact_ms", "local_surface_ms", "total_ms", "cpu_total_ms", "vertex_variance_ms"):
        assert np.isfinite(result[key]) and result[key] > 0
    assert result["total_ms"] == pytest.approx(result["add_contact_ms"] + result["local_surface_ms"])
    assert result["n_vertices"] > 0 and result["n_faces"] > 0


def _row(n: float, res: float, without: float, with_variance: float) -> dict[str, float]:
    return {
        "n_contacts": n,
        "resolution_m": res,
        "cpu_total_without_variance_ms": without,
        "cpu_total_ms": with_variance,
    }


def test_goal_check_uses_200_contacts_at_the_default_grid() -> None:
    rows = [_row(200, 0.004, 1.0, 1.0), _row(400, 0.005, 1.0, 1.0), _row(200, 0.005, 12.0, 25.0)]
    goal = bench_gpis.goal_check(rows, 0.005)
    assert goal is not None
    assert (goal["igef_cpu_ms"], goal["gpv_cpu_ms"]) == (12.0, 25.0)
    assert goal["igef_pass"] and not goal["gpv_pass"]
    assert bench_gpis.goal_check(rows[:2], 0.005) is None


def test_too_few_contacts_for_the_repeats_says_what_to_do() -> None:
    args = argparse.Namespace(quick=True, json=False, contacts=[3], resolutions=None, repeats=3, seed=0)
    with pytest.raises(BenchmarkError, match="give N >= 4"):
        bench_gpis.main(args)


def test_gpis_is_a_bench_sub_command() -> None:
    from palpate.cli import build_parser

    args = build_parser().parse_args(["bench", "gpis", "--quick", "--json", "--contacts", "50", "200"])
    assert args.quick and args.json and args.contacts == [50, 200] and args.resolutions is None


def test_scaling_run_prints_rows_with_the_issue_keys_and_pass_last(capsys: Any) -> None:
    """The smallest scaling run (`palpate bench gpis` without --resolutions): the JSON shape of issue 11."""
    args = argparse.Namespace(quick=True, json=True, contacts=[12], resolutions=None, repeats=2, seed=1, shapes=None)
    code = bench_gpis.main(args)
    last = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert isinstance(last["pass"], bool) and code == (0 if last["pass"] else 1)
    (row,) = last["rows"]
    for key in ("contacts", "igef_ms", "gpv_ms", "peak_mb", "surface_err_mm_p95"):
        assert math.isfinite(row[key]), key
    assert row["contacts"] == 12 and row["ran"] == "exact" and row["shape"] == "ellipsoid"
    assert row["gpv_ms"] >= row["igef_ms"] > 0 and row["approx_vs_exact_mm_p95"] == 0.0
    assert row["exact_igef_ms"] > 0  # the exact reference ran too (12 <= the exact limit)


def test_scaling_goals_name_what_a_row_misses() -> None:
    from palpate.bench.gpis_scale import check_row

    row = {"contacts": 2000, "igef_ms": 15.0, "gpv_ms": 45.0, "peak_mb": 100.0, "approx_vs_exact_mm_p95": 0.3}
    assert check_row(row) == ["GP-V 45.0 > 40 ms", "vs exact 0.300 > 0.2 mm"]
    assert check_row({**row, "gpv_ms": 30.0, "approx_vs_exact_mm_p95": 0.01}) == []
    assert check_row({**row, "contacts": 10_000, "peak_mb": 2000.0, "gpv_ms": 30.0}) == [
        "peak 2000 > 1024 MB",
        "vs exact 0.300 > 0.2 mm",
    ]


def test_a_row_whose_process_fails_is_named_in_the_table_the_goals_and_the_json(
    monkeypatch: pytest.MonkeyPatch, capsys: Any
) -> None:
    """Session 42's walkthrough: a row that ran out of memory ended the benchmark with the child's
    traceback and no JSON. The row holds its error (the process's last line, or the signal that
    killed it), the other rows are measured, and the benchmark fails with its JSON."""
    import subprocess

    from palpate.bench import gpis_scale

    def fake(shape: str, n: int, estimator: str, repeats: int, seed: int) -> dict[str, Any]:
        if n == 30:
            code = -9 if estimator == "auto" else 1
            done = subprocess.CompletedProcess([], code, "", "Traceback ...\nMemoryError: Unable to allocate 30 GiB\n")
            raise BenchmarkError(f"{estimator} GP, {n} contacts: {gpis_scale._why_failed(done)}")
        return gpis_scale.measure_row(shape, n, estimator, repeats, seed)

    monkeypatch.setattr(gpis_scale, "_row_in_subprocess", fake)
    args = argparse.Namespace(
        quick=True, json=True, contacts=[12, 30], resolutions=None, repeats=2, seed=1, shapes=None
    )
    assert bench_gpis.main(args) == 1
    out = capsys.readouterr().out.strip().splitlines()
    last = json.loads(out[-1])
    assert not last["pass"] and [r["contacts"] for r in last["rows"]] == [12, 30]
    failed = "auto GP, 30 contacts: its process was killed by SIGKILL (the kernel's out-of-memory killer sends SIGKILL)"
    assert last["rows"][1]["error"] == failed and last["missed"] == {"ellipsoid 30": [failed]}
    assert any(line.split()[:3] == ["ellipsoid", "30", "error"] for line in out)
    assert "goal ellipsoid 30: MISSED (" + failed + ")" in out
    done = subprocess.CompletedProcess([], 1, "", "Traceback ...\nMemoryError: Unable to allocate 30 GiB\n")
    assert gpis_scale._why_failed(done) == "MemoryError: Unable to allocate 30 GiB"
