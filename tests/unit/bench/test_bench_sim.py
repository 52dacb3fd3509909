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


def _row(scene: str) -> dict[str, Any]:
    return {
        "scene": scene,
        "timestep_s": 0.002,
        "bodies": 2,
        "geoms": 3,
        "dof": 6,
        "actuators": 0,
        "contact_pairs": 0,
        "exact_contact_spheres": 1,
        "bare_steps_s": 1e5,
        "inprocess_steps_s": 3000.0,
        "graph_steps_s": 2000.0,
        "graph_rtf": 4.0,
        "runtime_overhead": 1.5,
        "contacts": 10.0,
        "inprocess_breakdown_ms": {"step": 0.3, "driver.inputs": 0.05, "transfer": 0.02},
        "graph_breakdown_ms": {
            "tick_ms": 2.0,
            "step_ms": 0.4,
            "encode_ms": 0.1,
            "round_trip_ms": 1.2,
            "ack_hop_ms": 0.2,
            "source_dispatch_ms": 0.05,
            "clock_hop_ms": {"driver": 0.3},
            "wait_ms": {"driver": 0.01},
            "handle_ms": {"driver": 0.5},
        },
    }


def test_tables_have_a_row_per_scene_and_the_breakdown_names_every_part() -> None:
    rows = [_row("probe"), _row("hand")]
    for text in (bench_sim.table(rows), bench_sim.sizes_table(rows)):
        lines = text.splitlines()
        assert len(lines) == 4 and lines[2].split()[0] == "probe" and lines[3].split()[0] == "hand"
    assert bench_sim.table(rows).splitlines()[2].split()[6] == "0.030"  # in-process / bare
    text = bench_sim.breakdown_text(rows[0])
    for part in ("step 0.300", "driver.inputs 0.050", "round trip 1.200", "ack hop 0.200", "driver hop 0.300"):
        assert part in text


def test_model_sizes_count_what_each_scene_builds() -> None:
    from palpate.config import load
    from palpate.nodes.sim.core import Simulation
    from palpate.nodes.sim.model_stats import model_sizes
    from palpate.nodes.sim.scene import SceneConfig

    sizes = {}
    for effector in bench_sim.SCENES:
        for kind in ("box", "torus"):
            sim = Simulation(load(SceneConfig, {"effector": effector, "object": {"kind": kind}}, "scene"))
            sizes[effector, kind] = (model_sizes(sim.model), sim.exact_contact_spheres)
    probe, spheres = sizes["probe", "box"]
    assert probe == {"bodies": 2, "geoms": 3, "dof": 6, "actuators": 0, "contact_pairs": 0} and spheres == 1
    finger, spheres = sizes["finger", "box"]
    # object, metacarpal and three phalanges; the metacarpal is fixed, so only the phalanges meet the box
    assert finger == {"bodies": 5, "geoms": 5, "dof": 4, "actuators": 4, "contact_pairs": 3} and spheres == 0
    hand, _ = sizes["hand", "box"]
    assert (hand["bodies"], hand["dof"], hand["contact_pairs"]) == (17, 21, 15)  # 15 moving segments
    for effector in ("finger", "hand"):  # on a torus the exact sensor senses capsule spheres, MuJoCo nothing
        model, spheres = sizes[effector, "torus"]
        assert model["contact_pairs"] == 0 and spheres > 10 * (model["dof"] // 4)


def test_breakdown_of_a_timed_graph(tmp_path: Path) -> None:
    from palpate.runtime.timing import breakdown

    source = {
        str(t): {
            "step": t,
            "stepped": t + 0.2,
            "encode_s": 0.01,
            "clock_sent": t + 0.21,
            "acked": t + 0.61,
            "dispatched": t + 0.62,
        }
        for t in range(5)
    }
    follower = {
        str(t): {"clock_received": t + 0.31, "ready": t + 0.32, "encode_s": 0.02, "ack_sent": t + 0.52}
        for t in range(5)
    }
    (tmp_path / "sim.json").write_text(json.dumps({"node": "sim", "clock_source": True, "ticks": source}))
    (tmp_path / "driver.json").write_text(json.dumps({"node": "driver", "clock_source": False, "ticks": follower}))
    out = breakdown(tmp_path, first_tick=1)
    assert out["ticks"] == 3  # ticks 1-3: tick 4 has no successor to end it
    for key, want in (
        ("tick_ms", 1000),
        ("step_ms", 190),
        ("encode_ms", 30),
        ("round_trip_ms", 400),
        ("ack_hop_ms", 90),
        ("source_dispatch_ms", 10),
    ):
        assert out[key] == pytest.approx(want), key
    assert out["clock_hop_ms"]["driver"] == pytest.approx(100)
    assert out["wait_ms"]["driver"] == pytest.approx(10)
    assert out["handle_ms"]["driver"] == pytest.approx(200)
    assert out["trailing"] == []
    # a trailing node acknowledges after the clock source went on: out of the round trip's ack hop
    late = {str(t): {**follower[str(t)], "ack_sent": t + 0.9} for t in range(5)}
    (tmp_path / "noise.json").write_text(json.dumps({"node": "noise", "clock_source": False, "ticks": late}))
    sim = {"node": "sim", "clock_source": True, "trailing": ["noise"], "ticks": source}
    (tmp_path / "sim.json").write_text(json.dumps(sim))
    out = breakdown(str(tmp_path), first_tick=1)  # the folder as the docs write it: a str will do
    assert out["trailing"] == ["noise"] and out["ack_hop_ms"] == pytest.approx(90)
    assert out["handle_ms"]["noise"] == pytest.approx(580)
    (tmp_path / "other.json").write_text(json.dumps({"node": "x", "clock_source": True, "ticks": {}}))
    with pytest.raises(ValueError, match="one clock source"):
        breakdown(tmp_path)


# --- contacts -------------------------------------------------------------------------------------------


def test_both_benchmarks_are_sub_commands() -> None:
    from palpate.cli import build_parser

    parser = build_parser()
    args = parser.parse_args(["bench", "contacts", "--objects", "x", "--touches", "5", "--json"])
    assert (args.objects, args.touches, args.json) == (Path("x"), 5, True)
    args = parser.parse_args(["bench", "sim", "--quick", "--scenes", "probe", "hand"])
    assert args.quick and args.scenes == ["probe", "hand"]


def test_in_process_run_reports_where_its_ticks_go(tmp_path: Path) -> None:
    timing = tmp_path / "t.json"
    args = ["object:=box", "start:=[0.0, 0.0, 0.03]", "duration_s:=0.3"]
    bench_sim.run_in_process(bench_sim.PROBE_LAUNCH, args, timing, warmup_s=0.1)
    parts = json.loads(timing.with_suffix(".parts.json").read_text())
    assert parts["ticks"] == 31 - 10  # ticks 10-30 of 31
    ms = parts["ms_per_tick"]
    assert {
        "step",
        "transfer",
        "driver.inputs",
        "driver.on_tick",
        "noise.inputs",
        "noise.on_tick",
        "sim.inputs",
    } == set(ms)
    assert all(v > 0 for v in ms.values())
    assert ms["transfer"] < ms["step"] + ms["driver.on_tick"] + ms["noise.inputs"]  # inside them
