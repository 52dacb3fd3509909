"""`palpate bench sim`: the pure parts, the timing nodes and the CLI errors (and that both sim and contacts
are sub-commands)."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from palpate.bench import sim as bench_sim
from palpate.errors import BenchmarkError
from palpate.messages import codec
from palpate.messages.base import Message
from palpate.messages.schemas import ContactSet


class FakeCtx:
    def __init__(self) -> None:
        self.published: list[tuple[str, Any]] = []
        self.log = logging.getLogger("test.bench")

    def publish(self, port: str, message: Message) -> None:
        codec.validate(message)
        self.published.append((port, message))


def _contact(normal: list[float]) -> ContactSet:
    return ContactSet(
        stamp_ns=0,
        positions_m=np.zeros((1, 3)),
        local_positions_m=np.zeros((1, 3)),
        normals=np.array([normal], dtype=np.float64),
        forces_n=np.ones(1),
        links=["probe"],
    )


def _empty() -> ContactSet:
    z = np.zeros((0, 3))
    return ContactSet(stamp_ns=0, positions_m=z, local_positions_m=z, normals=z, forces_n=np.zeros(0), links=[])


def test_probe_driver_descends_then_presses_and_slides_then_returns(tmp_path: Path) -> None:
    ctx = FakeCtx()
    timing = tmp_path / "t.json"
    cfg = bench_sim.ProbeDriverConfig(timing_path=str(timing))
    driver = bench_sim.ProbeDriver(cfg, ctx)
    driver.on_tick(0)
    np.testing.assert_allclose(ctx.published[-1][1].linear_m_s, [0, 0, -cfg.approach_speed_m_s])
    n = np.array([0.0, 0.6, 0.8])
    driver.on_contacts(_contact(list(n)))
    driver.on_tick(10_000_000)
    v = ctx.published[-1][1].linear_m_s
    assert v @ n == pytest.approx(-cfg.press_speed_m_s)  # pressing into the surface
    tangential = v - (v @ n) * n
    assert np.linalg.norm(tangential) == pytest.approx(cfg.slide_speed_m_s)  # sliding along it
    driver.on_contacts(_empty())
    driver.on_tick(20_000_000)
    np.testing.assert_allclose(ctx.published[-1][1].linear_m_s, -cfg.approach_speed_m_s * n)  # back along the normal
    driver.close()
    data = json.loads(timing.read_text())
    assert data["stamps_ns"] == [0, 10_000_000, 20_000_000] and data["contacts"] == 1
    assert data["wall_s"] == sorted(data["wall_s"])


def test_rate_from_timing_skips_the_warm_up(tmp_path: Path) -> None:
    path = tmp_path / "t.json"
    stamps = [k * 10_000_000 for k in range(101)]  # 1 s of 10 ms ticks
    # 0.25 s per tick during the first 0.2 s (start-up), then 2 ms per 10 ms tick: 5x real time
    wall = [100.0 + 0.25 * k if k < 20 else 105.0 + 0.002 * k for k in range(101)]
    path.write_text(json.dumps({"stamps_ns": stamps, "wall_s": wall, "contacts": 7}))
    rate = bench_sim.rate_from_timing(path, warmup_s=0.2)
    assert rate["sim_s"] == pytest.approx(0.8)
    assert rate["rtf"] == pytest.approx(5.0)
    assert rate["contacts"] == 7
    with pytest.raises(BenchmarkError, match="only 101 ticks recorded"):
        bench_sim.rate_from_timing(path, warmup_s=5.0)


def test_scene_launch_files_validate(tmp_path: Path) -> None:
    from palpate.launch.graph import resolve
    from palpate.launch.loader import load_launch, parse_cli_args

    obj = {"kind": "box"}
    for scene in bench_sim.SCENES:
        launch, args = bench_sim.scene_launch(scene, obj, bench_sim.QUICK, tmp_path)
        graph = resolve(load_launch(launch, parse_cli_args([*args, "timing:=x.json"])), bus_dir=tmp_path / "bus")
        sim = graph.by_name["sim"]
        assert sim.params["scene"]["effector"] == scene
        assert sim.params["duration_s"] == bench_sim.QUICK.duration_s
        timer = graph.by_name["driver" if scene == "probe" else "sink"]
        assert timer.params["timing_path"] == "x.json"
    start = bench_sim.probe_start(obj)
    assert start[2] == pytest.approx(0.015 + 0.008 + 0.012)  # the default box is 30 mm high


def test_object_falls_back_to_a_box_without_ycb(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("PALPATE_YCB_DIR", str(tmp_path / "absent"))
    obj, note = bench_sim.object_section()
    assert obj == {"kind": "box"} and "YCB meshes not found" in note


def test_table_has_a_row_per_scene() -> None:
    row = {
        "scene": "probe",
        "timestep_s": 0.002,
        "bare_steps_per_s": 1e5,
        "inprocess_steps_per_s": 3000.0,
        "graph_steps_per_s": 2000.0,
        "graph_rtf": 4.0,
        "runtime_overhead": 1.5,
        "bare_over_graph": 50.0,
        "contacts": 10.0,
    }
    lines = bench_sim.table([row, {**row, "scene": "hand"}]).splitlines()
    assert len(lines) == 4 and lines[2].split()[0] == "probe" and lines[3].split()[0] == "hand"


# --- contacts -------------------------------------------------------------------------------------------


def test_both_benchmarks_are_sub_commands() -> None:
    from palpate.cli import build_parser

    parser = build_parser()
    args = parser.parse_args(["bench", "contacts", "--objects", "x", "--touches", "5", "--json"])
    assert (args.objects, args.touches, args.json) == (Path("x"), 5, True)
    args = parser.parse_args(["bench", "sim", "--quick", "--scenes", "probe", "hand"])
    assert args.quick and args.scenes == ["probe", "hand"]
