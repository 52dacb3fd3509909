"""The speed-accuracy sweep returns one row per configuration (a tiny run)."""

from __future__ import annotations

import math

from palpate.nodes.mapper.sweep import format_rows, sweep


def test_tiny_sweep_returns_rows() -> None:
    rows = sweep(Ks=(2,), resolutions_mm=(4.0,), duration_s=0.5, measure_memory=True)
    assert [(r.method, r.K) for r in rows] == [("known", 0), ("dead_reckoning", 0), ("fastslam", 2)]
    for r in rows:
        assert 0.0 <= r.rmse <= 1.0 and r.ms_per_update > 0 and r.peak_memory_mb > 0
        assert math.isfinite(r.accuracy_mm)
    assert "fastslam" in format_rows(rows)
    assert set(rows[0].as_dict()) >= {"K", "resolution_mm", "rmse", "ms_per_update", "peak_memory_mb"}
