"""The SLAM evaluation's pure parts: aggregation over seeds, the JSON summary, tables, truth and maps."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from palpate.errors import ConfigError, LaunchError
from palpate.evaluation.slam import (
    METHODS,
    OWN_ARGUMENT_HINTS,
    BoxTruth,
    Capture,
    SlamEvalConfig,
    aggregate,
    explored_mask,
    format_table,
    sparse_map,
    summary_json,
)
from palpate.evaluation.sweep_slam import format_table as sweep_table
from palpate.messages import codec
from palpate.messages.schemas import ContactSet, OccupancyGrid
from palpate.nodes.mapper.grid import GridSpec, SparseMap
from palpate.nodes.mapper.metrics import map_rmse


def _row(seed: int, method: str, t: float, rmse: float, acc: float = 1.0) -> dict[str, float | int | str]:
    return {
        "seed": seed,
        "method": method,
        "time_s": t,
        "rmse": rmse,
        "rmse_explored": rmse / 2,
        "accuracy_mm": acc,
        "completeness_mm": 2 * acc,
        "occupied_cells": 10 * seed,
    }


def _rows() -> list[dict[str, float | int | str]]:
    rows = []
    for seed, (k, f, d) in enumerate([(0.20, 0.25, 0.40), (0.22, 0.29, 0.44), (0.18, 0.27, 0.36)]):
        for t, scale in ((10.0, 1.5), (100.0, 1.0)):
            rows += [
                _row(seed, "dead_reckoning", t, d * scale),  # out of table order on purpose
                _row(seed, "known", t, k * scale, acc=0.5 + seed),
                _row(seed, "fastslam", t, f * scale),
            ]
    return rows


def test_aggregate_takes_mean_and_sample_std_per_method_and_time_in_table_order() -> None:
    summary = aggregate(_rows())
    assert [(s["method"], s["time_s"]) for s in summary] == [(m, t) for m in METHODS for t in (10.0, 100.0)]
    known_100 = summary[1]
    assert known_100["n"] == 3
    np.testing.assert_allclose(known_100["rmse"], np.mean([0.20, 0.22, 0.18]), rtol=1e-12)
    np.testing.assert_allclose(known_100["rmse_std"], np.std([0.20, 0.22, 0.18], ddof=1), rtol=1e-12)
    np.testing.assert_allclose(known_100["accuracy_mm"], 1.5, rtol=1e-12)  # 0.5, 1.5, 2.5
    np.testing.assert_allclose(known_100["accuracy_mm_std"], 1.0, rtol=1e-12)
    np.testing.assert_allclose(summary[0]["rmse"], 1.5 * 0.20, rtol=1e-12)  # 10 s row
    np.testing.assert_allclose(known_100["occupied_cells"], 10.0, rtol=1e-12)


def test_aggregate_of_one_seed_has_zero_std_and_unknown_methods_go_last() -> None:
    summary = aggregate([_row(0, "zzz", 5.0, 0.3), _row(0, "known", 5.0, 0.1)])
    assert [s["method"] for s in summary] == ["known", "zzz"]
    assert summary[0]["rmse_std"] == 0.0 and summary[0]["n"] == 1


def test_aggregate_propagates_an_infinite_distance() -> None:
    rows = [_row(0, "known", 1.0, 0.1, acc=math.inf), _row(1, "known", 1.0, 0.1, acc=1.0)]
    assert aggregate(rows)[0]["accuracy_mm"] == math.inf


def test_summary_json_holds_the_100s_means_and_the_ordering_checks() -> None:
    timing = [{"seed": s, "ms_per_tick": 10.0 + s, "ms_per_update_fastslam": 6.0} for s in range(3)]
    out = summary_json(aggregate(_rows()), timing)
    np.testing.assert_allclose(out["rmse_known"], 0.20, atol=1e-4)
    np.testing.assert_allclose(out["rmse_fastslam"], 0.27, atol=1e-4)
    np.testing.assert_allclose(out["rmse_dead_reckoning"], 0.40, atol=1e-4)
    np.testing.assert_allclose(out["rmse_known_10s"], 0.30, atol=1e-4)
    assert out["fastslam_beats_dead_reckoning"] is True and out["known_best"] is True
    assert out["seeds"] == [0, 1, 2] and out["time_s"] == 100.0
    np.testing.assert_allclose(out["ms_per_tick"], 11.0, rtol=1e-12)
    assert "ms_per_update_known" not in out  # absent from every timing row


def test_summary_json_reports_a_failed_ordering() -> None:
    rows = [_row(0, "known", 100.0, 0.3), _row(0, "fastslam", 100.0, 0.5), _row(0, "dead_reckoning", 100.0, 0.4)]
    out = summary_json(aggregate(rows), [{"seed": 0}])
    assert out["fastslam_beats_dead_reckoning"] is False and out["known_best"] is True
    with pytest.raises(ConfigError):
        summary_json([], [])


def test_table_has_a_line_per_method_and_time() -> None:
    text = format_table(aggregate(_rows()))
    lines = text.splitlines()
    assert len(lines) == 2 + 6
    assert lines[2].split()[:3] == ["known", "10", "3"]
    assert "0.200 +- 0.020" in text  # known at 100 s


def test_sweep_table_lists_every_row() -> None:
    row = {
        "method": "fastslam",
        "K": 100,
        "resolution_mm": 2.0,
        "rmse": 0.3,
        "rmse_explored": 0.1,
        "accuracy_mm": 0.6,
        "completeness_mm": 3.0,
        "ms_per_update": 7.5,
        "cpu_ms_per_update": 7.4,
        "peak_memory_mb": 12.0,
    }
    lines = sweep_table([row, {**row, "K": 300}]).splitlines()
    assert len(lines) == 4 and lines[3].split()[:3] == ["fastslam", "300", "2.0"]


def test_publish_period_lands_on_every_snapshot() -> None:
    assert SlamEvalConfig(snapshot_s=(10.0, 100.0)).publish_period_s() == 10.0
    assert SlamEvalConfig(snapshot_s=(2.5, 10.0)).publish_period_s() == 2.5
    args = SlamEvalConfig(seeds=(3,), snapshot_s=(1.0, 3.0)).arguments(3)
    assert args["seed"] == 3 and args["duration_s"] == 3.0 and args["publish_period_s"] == 1.0
    with pytest.raises(ConfigError):
        SlamEvalConfig(seeds=())
    with pytest.raises(ConfigError):
        SlamEvalConfig(snapshot_s=(0.0,))
    # --arg must not override what the evaluation sets itself (every seed would run as seed 0)
    with pytest.raises(ConfigError, match=r"\(--arg\) seed: the evaluation sets these launch arguments itself"):
        SlamEvalConfig(launch_args={"seed": 0})
    assert set(OWN_ARGUMENT_HINTS) == set(SlamEvalConfig().own_arguments(0))
    assert SlamEvalConfig(launch_args={"free_reward": True}).arguments(1)["free_reward"] is True


def test_the_free_margin_follows_the_resolution_as_measured_unless_given() -> None:
    """An outside walkthrough: --resolution-mm 4 kept the 0.5 mm margin of 2 mm cells, and the known-pose
    map scored 0.331 instead of 0.021 (sweep slam took the margin of each resolution already)."""
    assert SlamEvalConfig().arguments(0)["free_margin_m"] == pytest.approx(0.0005)
    assert SlamEvalConfig(resolution_m=0.004).arguments(0)["free_margin_m"] == pytest.approx(0.0025)
    assert SlamEvalConfig(resolution_m=0.001).arguments(0)["free_margin_m"] == pytest.approx(0.0015)
    assert SlamEvalConfig(resolution_m=0.003).arguments(0)["free_margin_m"] is None  # the mapper's one cell
    given = SlamEvalConfig(resolution_m=0.004, launch_args={"free_margin_m": None})
    assert given.arguments(0)["free_margin_m"] is None


def test_an_unknown_launch_argument_is_refused_before_any_run() -> None:
    """An outside walkthrough: `--arg object=mesh` started a cluster and failed every seed (and --resume
    would have failed them again)."""
    from palpate.evaluation.slam import check_launch

    with pytest.raises(LaunchError, match=r"slam_eval\.yaml:\d+: unknown launch argument 'object'"):
        check_launch(SlamEvalConfig(launch_args={"object": "mesh"}))
    check_launch(SlamEvalConfig(launch_args={"free_reward": True}))
    # an outside walkthrough: 50 mm cells (one or two across the 90 mm region) ran, scoring nothing
    with pytest.raises(ConfigError, match=r"^--resolution-mm 30: cells of that size leave fewer than 4 across"):
        check_launch(SlamEvalConfig(resolution_m=0.03))
    with pytest.raises(LaunchError, match=r"resolution_m 0\.05 leaves fewer than 2 cells across"):  # the mapper's own
        check_launch(SlamEvalConfig(resolution_m=0.05))
    # an outside walkthrough: at 10 mm the finger holds no free-volume point and every map scored rmse 0
    with pytest.raises(ConfigError, match=r"^--resolution-mm 10: the finger holds no free-volume point"):
        check_launch(SlamEvalConfig(resolution_m=0.01))
    check_launch(SlamEvalConfig(resolution_m=0.006))
    # an outside walkthrough: 1e8 particles started the cluster, failed in a worker, was retried, and
    # was then offered --resume
    with pytest.raises(ConfigError, match=r"^n_particles = 100000000 maps need .* GiB"):
        check_launch(SlamEvalConfig(n_particles=100_000_000))


def test_box_truth_from_the_vertices_of_a_box_and_not_of_anything_else() -> None:
    corners = np.array([[x, y, z] for x in (-1, 3) for y in (0, 2) for z in (-5, 5)], dtype=np.float64) * 0.01
    box = BoxTruth.from_vertices(corners)
    np.testing.assert_allclose(box.center_m, [0.01, 0.01, 0.0], atol=1e-15)
    np.testing.assert_allclose(box.half_m, [0.02, 0.01, 0.05], atol=1e-15)
    np.testing.assert_allclose(box.sdf(np.array([[0.01, 0.01, 0.0], [0.04, 0.01, 0.0]])), [-0.01, 0.01], atol=1e-15)
    with pytest.raises(ConfigError, match="axis-aligned boxes"):
        BoxTruth.from_vertices(np.vstack([corners, [[0.0, 0.01, 0.0]]]))  # an inner vertex: not a box
    with pytest.raises(ConfigError):
        BoxTruth.from_vertices(corners[:4])


def test_sparse_map_survives_the_occupancy_grid_message() -> None:
    spec = GridSpec(origin_m=(-0.01, 0.0, 0.02), resolution_m=0.002, shape=(4, 5, 6))
    m = SparseMap(
        spec=spec, flat=np.array([0, 7, 119], dtype=np.int64), log_odds=np.array([2.0, -1.5, 0.25], np.float32)
    )
    message = OccupancyGrid(
        stamp_ns=0,
        map_kind="known",
        origin_m=np.array(spec.origin_m),
        resolution_m=spec.resolution_m,
        shape=np.array(spec.shape, dtype=np.int64),
        cell_indices=m.flat,
        log_odds=m.log_odds,
    )
    back = sparse_map(codec.decode(codec.encode(message), OccupancyGrid))
    assert back.spec == spec
    np.testing.assert_array_equal(back.flat, m.flat)
    np.testing.assert_array_equal(back.log_odds, m.log_odds)
    region, truth = np.array([0, 1, 7, 119]), np.array([True, False, False, True])
    assert map_rmse(back, region, truth) == map_rmse(m, region, truth)


def test_capture_keeps_maps_at_snapshot_stamps_and_every_contact() -> None:
    capture = Capture([10_000_000_000])
    grid = OccupancyGrid(
        stamp_ns=0,
        map_kind="known",
        origin_m=np.zeros(3),
        resolution_m=0.01,
        shape=np.ones(3, dtype=np.int64),
        cell_indices=np.zeros(0, dtype=np.int64),
        log_odds=np.zeros(0, dtype=np.float32),
    )
    capture(0, "mapper_known", "map/known", grid)  # not a snapshot stamp
    capture(1000, "mapper_known", "map/known", grid.__class__(**{**grid.__dict__, "stamp_ns": 10_000_000_000}))
    capture(1000, "mapper_known", "map/occupancy_weighted", grid)  # not one of the three maps
    contact = ContactSet(
        stamp_ns=0,
        positions_m=np.ones((2, 3)),
        local_positions_m=np.zeros((2, 3)),
        normals=np.tile([0.0, 0.0, 1.0], (2, 1)),
        forces_n=np.ones(2),
        links=["a", "b"],
    )
    capture(3, "sim", "sensors/contacts", contact)
    assert list(capture.maps) == [("known", 10_000_000_000)]
    assert capture.contact_points().shape == (2, 3)
    assert capture.n_messages == 4


def test_explored_mask_marks_points_within_the_radius() -> None:
    mask = explored_mask(np.array([[0.0, 0.0, 0.0]]), 0.01)
    assert mask(np.array([[0.0, 0.0, 0.009], [0.0, 0.011, 0.0]])).tolist() == [True, False]
    assert explored_mask(np.zeros((0, 3)), 0.01)(np.zeros((2, 3))).tolist() == [False, False]


def test_maps_png_is_written(tmp_path: Path) -> None:
    from palpate.evaluation.slam import plot_maps

    spec = GridSpec(origin_m=(-0.03, -0.03, -0.03), resolution_m=0.002, shape=(30, 30, 30))
    box = BoxTruth(center_m=np.zeros(3), half_m=np.full(3, 0.02))
    m = SparseMap(spec=spec, flat=np.array([5, 900, 26999], dtype=np.int64), log_odds=np.array([3, 1, -2], np.float32))
    path = tmp_path / "maps.png"
    plot_maps(path, {k: m for k in METHODS}, box, box.surface_points(0.005)[:10], "test")
    assert path.stat().st_size > 10_000


def test_launch_args_are_yaml_values() -> None:
    from palpate.launch.loader import parse_cli_args

    assert parse_cli_args(["free_reward=true", "free_margin_m=null", "particles=30"], separator="=") == {
        "free_reward": True,
        "free_margin_m": None,
        "particles": 30,
    }
    with pytest.raises(LaunchError, match="must look like name=value"):
        parse_cli_args(["free_reward"], separator="=")


def test_snapshot_times_set_the_runs_length_from_the_command_line() -> None:
    """An outside walkthrough: every evaluation ran 100 s a seed, with no option to shorten it."""
    import argparse

    from palpate.evaluation.slam import _snapshot_times

    assert _snapshot_times("1,2.5") == (1.0, 2.5)
    assert SlamEvalConfig(snapshot_s=_snapshot_times("5")).duration_s == 5.0
    assert _snapshot_times("0.01,0.5") == (0.01, 0.5)
    for bad in ("", "x", "5,2", "0,1", "1,1", "nan", "0.125", "0.001"):  # (the last two failed in every run)
        with pytest.raises(argparse.ArgumentTypeError):
            _snapshot_times(bad)


def test_a_seed_that_fails_with_palpates_own_error_is_a_row_not_a_retried_task(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Session 42's note: a deterministic error in a worker was retried twice (a seed runs for
    minutes) and left no row. It is the seed's row now, named, and the command fails."""
    import argparse

    from palpate.evaluation import slam
    from palpate.evaluation.dask_runs import Outcome

    def fails(seed: int, config: SlamEvalConfig, keep_maps: bool = False) -> dict[str, object]:
        raise ConfigError("the mapper's region holds no contact")

    monkeypatch.setattr(slam, "run_seed", fails)
    assert slam.run_seed_on_worker(3, SlamEvalConfig(), False) == {
        "seed": 3,
        "error": "ConfigError: the mapper's region holds no contact",
    }

    def ran(config: SlamEvalConfig, log: object, cluster: object, plot_seed: int | None = None) -> tuple:
        return [{"seed": 0, "error": "ConfigError: the mapper's region holds no contact"}], Outcome()

    monkeypatch.setattr(slam, "run_seeds", ran)
    parser = argparse.ArgumentParser()
    slam.configure(parser)
    args = parser.parse_args(["--seeds", "1", "--out", str(tmp_path / "out")])
    assert slam.main(args) == 1
    assert "run failed: seed 0: ConfigError: the mapper's region holds no contact" in capsys.readouterr().err


def test_a_sweep_whose_recording_holds_no_contact_is_refused_by_its_duration(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An outside audit: `sweep slam --duration-s 0.3` printed rows of NaN and inf and wrote them as normal."""
    from palpate.cli import main

    args = ["sweep", "slam", "--particles", "1", "--resolutions-mm", "2", "--duration-s", "0.3", "--no-memory"]
    assert main([*args, "--workers", "1", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "the finger made no contact in the 0.3 s recorded (seed 0)" in err and "--duration-s" in err
    assert not (tmp_path / "out" / "slam_sweep.json").exists()
