"""External nodes that die or fail the run: the launch ends, names them and exits 1. Each "driver" here is
palpate's own node process started from the spec the launcher writes for an external node (the wire is
the same as a driver's; tests/integration/test_drivers.py runs drivers that import no palpate)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from palpate.launch.supervisor import external_spec_path
from tests.integration.launch_helpers import child_env, kill_session, launched, text, wait_for

RUN_FAILER = "tests.integration.fake_nodes:RUN_FAILER"


def graph(tmp_path: Path, external: str, extra: str = "", mode: str = "lockstep") -> Path:
    """A cube that would run for 1000 s (100k ticks) and a consumer, `external` marked so."""
    path = tmp_path / "graph.yaml"
    path.write_text(f"""
mode: {mode}
nodes:
  - name: cube
    type: cube_contacts
    params: {{duration_s: 1000.0}}
    external: {str(external == "cube").lower()}
  - name: stats
    type: contact_stats
    external: {str(external == "stats").lower()}
{extra}""")
    return path


def start_driver(bus_dir: Path, name: str, driver_log: Path, log: Path) -> subprocess.Popen[bytes]:
    """Once the launcher has written the spec of external node `name`, start palpate's own node process
    from it (the "driver"), in its own session, its output in `driver_log`."""
    spec = external_spec_path(bus_dir, name)
    wait_for(spec.exists, 60, f"the spec of {name}", log)
    with driver_log.open("wb") as out:
        return subprocess.Popen(
            [sys.executable, "-m", "palpate.runtime.node", str(spec)],
            env=child_env(bus_dir),
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )


def kill_external_mid_run(tmp_path: Path, name: str, monkeypatch: pytest.MonkeyPatch) -> tuple[int, str]:
    """Launch the graph with `name` external, start it from its spec, SIGKILL it once the run is under way
    (the clock source has logged its progress: every node is past its start-up): the launch's exit code
    (within 30 s) and output."""
    monkeypatch.setenv("PALPATE_PROGRESS_S", "0.2")  # the clock source's "t = ..." lines, wherever it runs
    bus_dir, log = tmp_path / "bus", tmp_path / "launch.log"
    driver_log = tmp_path / f"{name}.log"
    with launched(graph(tmp_path, name), bus_dir, log) as proc:
        driver = start_driver(bus_dir, name, driver_log, log)
        try:
            wait_for(lambda: "INFO t = " in text(log) + text(driver_log), 60, "the run to be under way", log)
            os.kill(driver.pid, signal.SIGKILL)
            code = proc.wait(timeout=30)  # before the fix: a dead clock source left the run hanging for good
        finally:
            kill_session(driver)
    return code, text(log)


def test_a_dead_external_clock_source_ends_the_run_naming_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    code, out = kill_external_mid_run(tmp_path, "cube", monkeypatch)
    assert code == 1, out
    # the follower closes in order (its summary), as a failed run
    assert "ERROR node stats ended the run as a failure: the clock source 'cube' disconnected without a stop" in out
    assert "[stats] summary:" in out, out
    assert "[launch] node 'stats' (contact_stats) was the first of its nodes to end the run as a failure" in out, out


def test_a_dead_external_follower_is_named_at_once(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    code, out = kill_external_mid_run(tmp_path, "stats", monkeypatch)
    assert code == 1, out
    assert "'stats' disconnected without a stop (subscription hello/stats gone for" in out, out  # in seconds, not 120
    assert "[launch] node 'cube' (cube_contacts) died with exit code 3" in out, out


def test_a_node_that_publishes_runcontrol_fail_makes_the_run_fail(tmp_path: Path) -> None:
    """What a driver publishes to fail the run (here from a palpate node, as a driver would send it):
    the clock source stops the run as a failure, and the launch exits 1."""
    extra = f"""  - name: failer
    type: {RUN_FAILER}
    params: {{after_ticks: 5}}"""
    log = tmp_path / "launch.log"
    with launched(graph(tmp_path, "", extra), tmp_path / "bus", log) as proc:
        assert proc.wait(timeout=60) == 1, text(log)
    out = text(log)
    assert "run stopped at t = 0.040 s: run_failer: sensor lost after 5 ticks" in out, out
    reason = "run_failer: sensor lost after 5 ticks (asked by a RunControl 'fail')"
    assert f"ERROR node cube ended the run as a failure: {reason}" in out, out
    # every node ends as a failure, the first to exit is named (the clock source passes the "fail" on: a
    # node that hears only the clock learns the run failed)
    assert re.search(
        r"\[launch\] node '\w+' \([\w.:]+\) was the first of its nodes to end the run as a failure", out
    ), out
    assert "ERROR node stats ended the run as a failure: run_failer: sensor lost after 5 ticks" in out, out


def test_a_hung_external_clock_source_is_named_by_its_followers(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An outside walkthrough: a clock-source driver that hung left the graph waiting for ever without a line."""
    monkeypatch.setenv("PALPATE_PROGRESS_S", "0.2")
    monkeypatch.setenv("PALPATE_WAIT_NOTE_S", "1.0")
    bus_dir, log, driver_log = tmp_path / "bus", tmp_path / "launch.log", tmp_path / "cube.log"
    with launched(graph(tmp_path, "cube"), bus_dir, log) as proc:
        driver = start_driver(bus_dir, "cube", driver_log, log)
        try:
            wait_for(lambda: "INFO t = " in text(driver_log), 60, "the run to be under way", log)
            os.kill(driver.pid, signal.SIGSTOP)  # hung: alive, subscribed, silent
            wait_for(lambda: "no tick for" in text(log), 30, "the follower to say it waits", log)
            assert re.search(
                r"node stats: no tick for \d+ s: waiting for tick \d+ from the clock source cube", text(log)
            )
        finally:
            os.kill(driver.pid, signal.SIGCONT)
            kill_session(driver)
            proc.send_signal(signal.SIGINT)
            proc.wait(timeout=30)


def test_a_real_time_driver_that_dies_is_named_and_its_return_too(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Session 42's walkthrough: in real time nothing waits for a driver, so one that died went unnoticed."""
    monkeypatch.setenv("PALPATE_PROGRESS_S", "0.2")
    bus_dir, log, driver_log = tmp_path / "bus", tmp_path / "launch.log", tmp_path / "stats.log"
    with launched(graph(tmp_path, "stats", mode="realtime"), bus_dir, log) as proc:
        driver = start_driver(bus_dir, "stats", driver_log, log)
        try:
            wait_for(lambda: "INFO t = " in text(log), 60, "the run to be under way", log)
            os.kill(driver.pid, signal.SIGKILL)
            driver.wait(timeout=10)
            gone = "node cube: 'stats' disconnected (subscription hello/stats gone for 2 s: its process died"
            wait_for(lambda: gone in text(log), 30, "the clock source to name the dead driver", log)
            driver = start_driver(bus_dir, "stats", driver_log, log)  # a restarted driver reconnects
            wait_for(lambda: "node cube: 'stats' reconnected" in text(log), 30, "the driver's return", log)
            assert proc.poll() is None, text(log)  # the real-time graph ran on
        finally:
            kill_session(driver)
            proc.send_signal(signal.SIGINT)
            proc.wait(timeout=30)
    assert text(log).count("'stats' disconnected") == 1, text(log)
