"""`palpate bench bus --json` with tiny iteration counts: the last line is JSON with the promised keys.

The latency ratio itself is not asserted here (machines are noisy); run the benchmark for that.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from typing import Any

from palpate.paths import REPO_ROOT

HEADLINE = ("latency_ratio_max", "latency_p50_us_small", "throughput_1mb_gbps")
PER_SIZE = ("palpate_p50_us", "palpate_p99_us", "raw_p50_us", "raw_p99_us", "palpate_gbps", "raw_gbps", "latency_ratio")


def numbers(value: Any) -> list[float]:
    """Every number in a JSON value (booleans are not numbers here)."""
    if isinstance(value, dict):
        return [x for v in value.values() for x in numbers(v)]
    if isinstance(value, bool) or not isinstance(value, int | float):
        return []
    return [float(value)]


def test_bench_bus_json_last_line_has_the_keys() -> None:
    command = [sys.executable, "-m", "palpate.cli", "bench", "bus", "--json", "--rounds", "1", "--pings", "5"]
    result = subprocess.run(
        [*command, "--stream", "10"], cwd=REPO_ROOT, capture_output=True, text=True, timeout=120, check=False
    )
    lines = result.stdout.strip().splitlines()
    assert result.returncode == (0 if json.loads(lines[-1])["pass"] else 1), result.stderr  # goals judged
    assert "| 64B |" in result.stdout and "| 1MB |" in result.stdout  # the table comes first
    summary = json.loads(lines[-1])
    for key in HEADLINE:
        assert key in summary, f"missing {key}"
    assert set(summary["sizes"]) == {"64B", "4KB", "1MB"}
    for size in summary["sizes"].values():
        for key in PER_SIZE:
            assert key in size, f"missing sizes.*.{key}"
    assert all(math.isfinite(v) for v in numbers(summary)), summary
    measured = [summary[key] for key in HEADLINE] + numbers(summary["sizes"])
    assert all(v > 0 for v in measured), summary
