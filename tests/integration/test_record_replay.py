"""Record, replay, recover and re-run: real `palpate` processes, each test on its own bus directory.

- a lockstep run of launch/demo_minimal.yaml recorded with `launch --record`: `bag info` counts;
- the same launch and seed recorded twice: byte-identical MCAP files (the demo, and FastSLAM, whose
  mapper's status would carry wall-clock timings if the runtime let it);
- `palpate replay --fast` recorded by `palpate record`: the same messages, byte for byte, in order;
- `palpate launch --replay` on the sensor topics of the log, or on the whole log: the estimator's meshes
  come out again;
- a recorder SIGKILLed in a real-time run: `bag recover` keeps everything up to the last second;
- a recorder SIGKILLed under `launch --record`: the launch stops at once and points at `bag recover`.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

import pytest
from mcap.reader import make_reader

from palpate.commands.introspect import TopicTap
from palpate.messages import codec, topics
from palpate.messages.schemas import Clock, NodeStatus
from palpate.paths import REPO_ROOT
from palpate.record.mcap_io import copy_log, read_messages, summarize
from tests.integration.launch_helpers import child_env

DEMO = REPO_ROOT / "launch" / "demo_minimal.yaml"
FASTSLAM = REPO_ROOT / "launch" / "fastslam.yaml"
TICKS = 100  # demo_minimal: duration 1 s at 10 ms per tick


def palpate(bus_dir: Path, *args: str, timeout_s: float = 120) -> subprocess.CompletedProcess[str]:
    """Run `palpate ARGS` to completion on `bus_dir`."""
    return subprocess.run(
        [sys.executable, "-m", "palpate.cli", *args],
        cwd=REPO_ROOT,
        env=child_env(bus_dir),
        capture_output=True,
        text=True,
        timeout=timeout_s,
    )


@contextmanager
def started(bus_dir: Path, log: Path, *args: str) -> Iterator[subprocess.Popen[bytes]]:
    """`palpate ARGS` in the background, in its own session; whatever is left of it is killed at the end."""
    with log.open("wb") as out:
        proc = subprocess.Popen(
            [sys.executable, "-m", "palpate.cli", *args],
            cwd=REPO_ROOT,
            env=child_env(bus_dir),
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        try:
            yield proc
        finally:
            with suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)


def launch_recorded(directory: Path, name: str, *extra: str, launch_file: Path = DEMO) -> Path:
    """Launch `launch_file` (the demo) with `--record`; returns the log, after checking the exit code."""
    out = directory / f"{name}.mcap"
    done = palpate(
        directory / f"bus-{name}",
        "launch",
        str(launch_file),
        *extra,
        "--record",
        str(out),
        "--bus",
        str(directory / f"bus-{name}"),
    )
    assert done.returncode == 0, done.stdout + done.stderr
    return out


def messages(path: Path, only: list[str] | None = None) -> list[tuple[str, bytes]]:
    return [(m.topic, m.data) for m in read_messages(path, only)]


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return launch_recorded(tmp_path_factory.mktemp("record"), "run")


def test_bag_info_reports_the_counts_of_a_recorded_run(recorded: Path, tmp_path: Path) -> None:
    done = palpate(tmp_path, "bag", "info", "--json", str(recorded))
    assert done.returncode == 0, done.stderr
    info = json.loads(done.stdout.strip().splitlines()[-1])
    assert info["topics"][topics.CONTACTS] == TICKS
    assert info["topics"][topics.SURFACE_MESH] == TICKS
    assert info["topics"][topics.CLOCK] == TICKS
    assert info["topics"][topics.LOCKSTEP_ACK] == 3 + 2 * TICKS  # tick -1 by all three, then two followers
    assert info["topics"][topics.GRAPH_CONTROL] == 1
    assert info["types"][topics.CONTACTS] == "ContactSet" and info["types"][topics.SURFACE_MESH] == "SurfaceMesh"
    assert (info["start_ns"], info["end_ns"]) == (0, (TICKS - 1) * 10_000_000)
    assert info["messages"] == sum(info["topics"].values())
    # the log says what made it (the same in every clone: the launch file relative to the repository)
    assert info["launch"]["launch_file"] == "launch/demo_minimal.yaml" and info["launch"]["seed"] == 0
    assert info["launch"]["args"]["duration_s"] == 1.0  # JSON values, not the strings stored
    text = palpate(tmp_path, "bag", "info", str(recorded))
    assert text.returncode == 0 and f"{topics.SURFACE_MESH}" in text.stdout
    assert "recorded by palpate launch launch/demo_minimal.yaml, seed 0" in text.stdout
    assert f"{info['messages']} messages on {len(info['topics'])} topics" in text.stdout
    assert "checked:" not in text.stdout  # only --check reads the chunks, and says so
    checked = palpate(tmp_path, "bag", "info", "--check", str(recorded))
    assert checked.returncode == 0, checked.stderr
    assert f"checked: every chunk's CRC, and {info['messages']} messages read as the summary counts" in checked.stdout


def test_a_lockstep_recording_closes_a_chunk_every_ten_ticks(recorded: Path) -> None:
    """Not one per tick: each chunk's index stays in the writer's memory until the log closes."""
    from mcap.reader import make_reader

    with recorded.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    assert TICKS // 10 <= len(summary.chunk_indexes) <= TICKS // 10 + 2  # the start-up's and the stop's


def test_same_launch_and_seed_give_the_same_bytes(recorded: Path, tmp_path: Path) -> None:
    again = launch_recorded(tmp_path, "again")
    assert again.read_bytes() == recorded.read_bytes()


def test_two_same_seed_fastslam_runs_give_the_same_bytes(tmp_path: Path) -> None:
    short = ("duration_s:=1.0", "particles:=20", "seed:=3")
    first, second = (launch_recorded(tmp_path, name, *short, launch_file=FASTSLAM) for name in ("a", "b"))
    statuses = [codec.decode(m.data, NodeStatus) for m in read_messages(first, [topics.NODE_STATUS])]
    mapper = [s for s in statuses if s.node == "mapper"]
    assert [s.state for s in mapper] == ["running", "running", "finished"]  # ticks 0 and 100, then the end
    metrics = dict(zip(mapper[-1].metric_names, mapper[-1].metric_values.tolist(), strict=True))
    assert metrics["updates"] == 101 and "ms_per_update" not in metrics  # a wall time: real-time statuses only
    assert first.read_bytes() == second.read_bytes()


def test_a_recorded_run_exports_for_foxglove(recorded: Path, tmp_path: Path) -> None:
    pytest.importorskip("foxglove")
    out = tmp_path / "foxglove.mcap"
    done = palpate(tmp_path, "bag", "export", str(recorded), "-o", str(out), "--foxglove")
    assert done.returncode == 0, done.stdout + done.stderr
    with out.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None and summary.statistics is not None
    counts = {
        (channel.topic, summary.schemas[channel.schema_id].name): summary.statistics.channel_message_counts[cid]
        for cid, channel in summary.channels.items()
    }
    assert counts[(topics.SURFACE_MESH, "foxglove.SceneUpdate")] == TICKS  # the estimator's box, every tick
    assert counts[(topics.CONTACTS, "foxglove.SceneUpdate")] == TICKS
    assert counts[(topics.NODE_STATUS, "palpate.NodeStatus")] > 0


def test_replayed_messages_equal_the_recorded_ones(recorded: Path, tmp_path: Path) -> None:
    bus_dir = tmp_path / "bus"
    out = tmp_path / "replayed.mcap"
    with started(
        bus_dir, tmp_path / "record.log", "record", "-o", str(out), "--until-stop", "--bus", str(bus_dir)
    ) as recorder:
        player = palpate(bus_dir, "replay", str(recorded), "--fast", "--bus", str(bus_dir))
        assert player.returncode == 0, player.stdout + player.stderr
        assert recorder.wait(timeout=60) == 0, (tmp_path / "record.log").read_text()
    replayed = messages(out)
    assert len(replayed) == summarize(recorded).messages
    assert replayed == messages(recorded)  # payloads, topics and order


def test_a_topic_no_publisher_sends_is_named_after_recording(recorded: Path, tmp_path: Path) -> None:
    """A misspelt topic records nothing: the recorder says so (it cannot refuse: a publisher may come later)."""
    bus_dir = tmp_path / "bus"
    out = tmp_path / "typo.mcap"
    log = tmp_path / "record.log"
    wanted = ["sensors/contact", topics.CONTACTS]
    with started(bus_dir, log, "record", "-o", str(out), *wanted, "--until-stop", "--bus", str(bus_dir)) as recorder:
        player = palpate(bus_dir, "replay", str(recorded), "--fast", "--bus", str(bus_dir))
        assert player.returncode == 0, player.stdout + player.stderr
        assert recorder.wait(timeout=60) == 0, log.read_text()
    text = log.read_text()
    assert "recorded no message on sensors/contact (see palpate topic list)" in text, text
    assert len(messages(out, [topics.CONTACTS])) == TICKS


def test_launch_replay_reruns_the_estimator_byte_for_byte(recorded: Path, tmp_path: Path) -> None:
    sensors = tmp_path / "sensors.mcap"  # the run without the estimator's output (`palpate bag filter`)
    copy_log(recorded, sensors, exclude=[topics.SURFACE_MESH])
    rerun = launch_recorded(tmp_path, "rerun", "--replay", str(sensors))
    meshes = messages(rerun, [topics.SURFACE_MESH])
    assert len(meshes) == TICKS
    assert meshes == messages(recorded, [topics.SURFACE_MESH])
    assert messages(rerun, [topics.CONTACTS, topics.CLOCK]) == messages(recorded, [topics.CONTACTS, topics.CLOCK])
    # the whole recording replays the sensors alone (the clock source): the estimator re-runs all the same
    again = launch_recorded(tmp_path, "again", "--replay", str(recorded))
    assert messages(again, [topics.SURFACE_MESH]) == messages(recorded, [topics.SURFACE_MESH])
    reporting = {codec.decode(data).node for _, data in messages(again, [topics.NODE_STATUS])}
    assert "estimator" in reporting and "cube" not in reporting  # it ran; the replay stood in for the sensor


@pytest.mark.slow
def test_recover_a_log_whose_recorder_was_killed(tmp_path: Path) -> None:
    bus_dir = tmp_path / "bus"
    bus_dir.mkdir()
    log = tmp_path / "killed.mcap"
    with (
        started(
            bus_dir,
            tmp_path / "launch.log",
            "launch",
            str(DEMO),
            "mode:=realtime",
            "duration_s:=30",
            "--bus",
            str(bus_dir),
        ) as launch,
        started(bus_dir, tmp_path / "record.log", "record", "-o", str(log), "--bus", str(bus_dir)) as recorder,
    ):
        tap = TopicTap(bus_dir, topics.CLOCK)
        latest = -1
        mark: int | None = None  # the first tick at 3 s of sim (and wall-clock) time
        deadline = time.monotonic() + 60
        while mark is None or latest < mark + 2_000_000_000:  # two more seconds: two flushes after the mark
            assert time.monotonic() < deadline and launch.poll() is None, (tmp_path / "launch.log").read_text()
            for _, payload in tap.receive(0.1):
                latest = max(latest, codec.decode(payload, Clock).stamp_ns)
            if mark is None and latest >= 3_000_000_000:
                mark = latest
        recorder.send_signal(signal.SIGKILL)
        assert recorder.wait(timeout=10) == -signal.SIGKILL
        tap.close()
    info = palpate(tmp_path, "bag", "info", str(log))
    assert info.returncode != 0 and "bag recover" in info.stderr  # no footer: not a complete log
    fixed = tmp_path / "fixed.mcap"
    done = palpate(tmp_path, "bag", "recover", str(log), "-o", str(fixed))
    assert done.returncode == 0, done.stdout + done.stderr
    summary = summarize(fixed)
    assert summary.topics[topics.CONTACTS] > 100 and summary.topics[topics.SURFACE_MESH] > 100
    # flushed every second: what the bus carried two seconds before the kill is on disk (a loaded
    # machine may hold the recorder up to a second behind the bus)
    assert mark is not None and summary.end_ns >= mark, (summary.end_ns, mark, latest)
    for message in read_messages(fixed):
        codec.decode(message.data)


def _child(parent: int, module: str, timeout_s: float = 30) -> int:
    """The pid of the child of `parent` that runs `python -m module`, once it is there."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for stat in Path("/proc").glob("[0-9]*/stat"):
            with suppress(OSError):
                pid, ppid = int(stat.parent.name), int(stat.read_text().rsplit(")", 1)[1].split()[1])
                if ppid == parent and module in (stat.parent / "cmdline").read_text():
                    return pid
        time.sleep(0.1)
    raise AssertionError(f"no child {module} of {parent}")


def test_a_recorder_killed_under_launch_stops_the_run_and_points_at_recover(tmp_path: Path) -> None:
    bus_dir, log = tmp_path / "bus", tmp_path / "run.mcap"
    args = ("launch", str(DEMO), "mode:=realtime", "duration_s:=60", "--record", str(log), "--bus", str(bus_dir))
    with started(bus_dir, tmp_path / "launch.log", *args) as launch:
        recorder = _child(launch.pid, "palpate.record.recorder")
        deadline = time.monotonic() + 60
        while not log.exists() or log.stat().st_size < 2000:  # recording: a chunk flushed
            assert time.monotonic() < deadline and launch.poll() is None, (tmp_path / "launch.log").read_text()
            time.sleep(0.1)
        os.kill(recorder, signal.SIGKILL)
        killed = time.monotonic()
        assert launch.wait(timeout=30) == 1
        assert time.monotonic() - killed < 15  # not the rest of the 60 s run
    out = (tmp_path / "launch.log").read_text()
    assert "the recorder died with signal SIGKILL; stopping the launch" in out, out
    assert f"palpate bag recover {log}" in out, out
    assert "exited with code" not in out, out  # an outside walkthrough: its death was said twice


def test_a_recorded_run_that_fails_before_its_first_tick_ends_at_once(tmp_path: Path) -> None:
    """The recorder waits for a stop that a run failing at start never sends: the launcher tells it to close."""
    log = tmp_path / "failed.mcap"
    bus_dir = tmp_path / "bus"
    explore = str(REPO_ROOT / "launch" / "explore.yaml")
    began = time.monotonic()
    done = palpate(
        bus_dir, "launch", explore, "object:=sphere", "start:=[0,0,0]", "--record", str(log), "--bus", str(bus_dir)
    )
    assert done.returncode == 1 and "lies inside the object" in done.stdout + done.stderr
    assert time.monotonic() - began < 29  # it waited 30 s for the recorder before (the graph's start counts here)
    assert summarize(log).topics.get(topics.LOCKSTEP_ACK, 0) >= 1  # complete, with the start-up acknowledgements


def test_a_closed_loop_graph_replays_its_sim(tmp_path: Path) -> None:
    """A review: the check that refuses commands no node reads refused `launch explore.yaml --replay LOG`,
    whose replay node stands in for the probe that read them (docs/runtime.md re-runs the planner so)."""
    explore = REPO_ROOT / "launch" / "explore.yaml"
    log = launch_recorded(tmp_path, "explore", "object:=sphere", "duration_s:=0.3", launch_file=explore)
    bus = tmp_path / "bus-replay"
    done = palpate(bus, "launch", str(explore), "object:=sphere", "duration_s:=0.3", "--replay", str(log), "--dry-run")
    assert done.returncode == 0, done.stdout + done.stderr
    assert "replay" in done.stdout
