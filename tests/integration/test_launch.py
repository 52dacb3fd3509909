"""`palpate launch` as a process: normal runs, Ctrl-C/SIGTERM with no orphans, dying and respawning nodes."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from palpate.paths import REPO_ROOT
from tests.integration.launch_helpers import alive, child_env, descendants, launched, node_pids, text, wait_for

CRASHER = "tests.integration.fake_nodes:CRASHER"
QUITTER = "tests.integration.fake_nodes:QUITTER"
FAILING_CLOCK = "tests.integration.fake_nodes:FAILING_CLOCK"
STUBBORN = "tests.integration.fake_nodes:STUBBORN"
TRAILING_ECHO = "tests.integration.fake_nodes:TRAILING_ECHO"
TICK_CHECK = "tests.integration.fake_nodes:TICK_CHECK"


def write(tmp_path: Path, body: str, name: str = "graph.yaml") -> Path:
    path = tmp_path / name
    path.write_text(body)
    return path


def long_graph(mode: str, extra: str = "") -> str:
    """A cube that would run for 1000 s (lockstep: 100k ticks) and a consumer, plus `extra` nodes."""
    return f"""
mode: {mode}
nodes:
  - name: cube
    type: cube_contacts
    params: {{duration_s: 1000.0}}
  - name: stats
    type: contact_stats
{extra}"""


def test_demo_minimal_runs_and_exits_zero(tmp_path: Path) -> None:
    log = tmp_path / "launch.log"
    with launched(REPO_ROOT / "launch" / "demo_minimal.yaml", tmp_path / "bus", log, "duration_s:=0.2") as proc:
        assert proc.wait(timeout=30) == 0, text(log)
    out = text(log)
    assert "[stats] summary: 20 contact sets, 80 contacts" in out
    assert "decode errors 0" in out
    assert node_pids(tmp_path / "bus") == {}  # manifests are removed at exit
    assert not list((tmp_path / "bus").glob("*.json"))
    assert not list((tmp_path / "bus").glob("*.pub"))  # and the ipc socket files


def run_until_quitter(tmp_path: Path, after_ticks: int, failed: bool = False) -> str:
    """The long lockstep graph with a node that stops the run after ``after_ticks`` ticks (as a failure
    with `failed`, and then the launch must exit 1): its output."""
    extra = f"""  - name: quitter
    type: {QUITTER}
    params: {{after_ticks: {after_ticks}, failed: {str(failed).lower()}}}"""
    log = tmp_path / "launch.log"
    with launched(write(tmp_path, long_graph("lockstep", extra)), tmp_path / "bus", log) as proc:
        assert proc.wait(timeout=60) == (1 if failed else 0), text(log)
    return text(log)


def test_a_node_that_stops_the_run_is_named_with_its_reason(tmp_path: Path) -> None:
    out = run_until_quitter(tmp_path, 5)
    assert re.search(r"\[cube\] INFO run stopped at t = 0\.0[45]0 s: quitter: done after 5 ticks", out), out
    assert "failure" not in out, out


def test_a_node_that_stops_the_run_as_a_failure_makes_the_launch_exit_1(tmp_path: Path) -> None:
    """The stop is as orderly as any (every node closes, the clock source names the reason), but the
    launch's exit code says the run failed, as a controller that found no surface asks."""
    out = run_until_quitter(tmp_path, 5, failed=True)
    assert re.search(r"\[cube\] INFO run stopped at t = 0\.0[45]0 s: quitter: done after 5 ticks", out), out
    assert "ERROR node quitter ended the run as a failure: quitter: done after 5 ticks" in out, out
    assert (
        "[launch] node 'quitter' (tests.integration.fake_nodes:QUITTER) was the first of its nodes to end the run as a"
        in out
    ), out
    assert "died" not in out, out
    assert node_pids(tmp_path / "bus") == {}  # every node closed


def failing_clock_run(tmp_path: Path, clock_params: str = "{}") -> str:
    """Launch a FAILING_CLOCK (with ``clock_params``) beside a quitter that waits 1000 ticks; the output of a
    launch that must exit 1 within 60 s."""
    graph = write(
        tmp_path,
        f"""
mode: lockstep
nodes:
  - name: clock
    type: {FAILING_CLOCK}
    params: {clock_params}
  - name: quitter
    type: {QUITTER}
    params: {{after_ticks: 1000}}
""",
    )
    log = tmp_path / "launch.log"
    with launched(graph, tmp_path / "bus", log) as proc:
        assert proc.wait(timeout=60) == 1, text(log)
    return text(log)


def test_a_clock_source_that_ends_the_run_as_a_failure_lets_the_others_close_and_exits_1(tmp_path: Path) -> None:
    out = failing_clock_run(tmp_path)
    assert "ERROR node clock ended the run as a failure: failing clock: gave up after 5 ticks" in out, out
    assert (
        "[launch] node 'clock' (tests.integration.fake_nodes:FAILING_CLOCK) was the first of its nodes to end the run"
        in out
    )
    assert "died" not in out, out
    assert node_pids(tmp_path / "bus") == {}


def test_a_lockstep_clock_that_goes_back_ends_the_run_naming_it_at_once(tmp_path: Path) -> None:
    """An outside walkthrough: a log recorded in real time whose clock went back, replayed in lockstep,
    had every follower refuse the Clock and the launch end 120 s later blaming the followers."""
    out = failing_clock_run(tmp_path, "{after_ticks: 100000, back_at_tick: 4}")
    assert (
        "ERROR node clock ended the run as a failure: clock: the clock's stamp at tick 3 is 0 ns, before tick 2's "
        "30000000 ns: a lockstep clock runs forward" in out
    ), out
    assert "no acknowledgement" not in out and "rejected message" not in out, out


def test_trailing_nodes_handle_each_input_in_its_own_tick(tmp_path: Path) -> None:
    """Nodes that feed nothing back to the clock source and say may_trail run behind it (the echo sleeps
    every tick), and still handle every input in the tick it was published in, directly from the clock
    source and through another trailing node."""
    extra = f"""  - name: echo
    type: {TRAILING_ECHO}
  - name: check
    type: {TICK_CHECK}"""
    graph = write(tmp_path, long_graph("lockstep", extra).replace("1000.0", "0.5"))
    dry = subprocess.run(
        [sys.executable, "-m", "palpate.cli", "launch", "--dry-run", str(graph), "--bus", str(tmp_path / "bus")],
        capture_output=True,
        text=True,
        check=True,
        cwd=REPO_ROOT,
        env=child_env(tmp_path / "bus"),
    ).stdout
    assert re.search(r"echo \(tests\.integration\.fake_nodes:TRAILING_ECHO\) \S+ \[trails\]", dry), dry
    assert re.search(r"check \(tests\.integration\.fake_nodes:TICK_CHECK\) \S+ \[trails\]", dry), dry
    log = tmp_path / "launch.log"
    with launched(graph, tmp_path / "bus", log) as proc:
        assert proc.wait(timeout=60) == 0, text(log)
    assert "check: 50 ticks, 100 inputs, 0 misfiled" in text(log), text(log)


def test_the_clock_source_reports_progress_while_the_graph_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("PALPATE_PROGRESS_S", "0.05")  # every 0.05 s of wall time instead of 30 s
    out = run_until_quitter(tmp_path, 1000)
    reports = re.findall(r"\[cube\] INFO t = (\d+\.\d) s after \d+ s of wall time \(\d+\.\d\dx real time\)", out)
    assert reports, out
    assert [float(t) for t in reports] == sorted(float(t) for t in reports)


@pytest.mark.parametrize(
    ("mode", "signum", "to_group"),
    [("realtime", signal.SIGINT, True), ("lockstep", signal.SIGTERM, False)],
    ids=["ctrl-c-realtime", "sigterm-lockstep"],
)
def test_signal_ends_every_child_without_orphans(tmp_path: Path, mode: str, signum: int, to_group: bool) -> None:
    bus_dir, log = tmp_path / "bus", tmp_path / "launch.log"
    with launched(write(tmp_path, long_graph(mode)), bus_dir, log) as proc:
        wait_for(lambda: set(node_pids(bus_dir)) == {"cube", "stats"}, 60, "both nodes to start", log)
        time.sleep(0.5)  # let them get into their loops
        pids = set(node_pids(bus_dir).values()) | set(descendants(proc.pid))
        assert len(pids) >= 2 and all(alive(p) for p in pids)
        start = time.monotonic()
        if to_group:
            os.killpg(proc.pid, signum)  # what a terminal's Ctrl-C does
        else:
            os.kill(proc.pid, signum)
        code = proc.wait(timeout=30)
        took = time.monotonic() - start
    out = text(log)
    assert code == 128 + signum, out
    assert f"received {signal.Signals(signum).name}: stopping every node" in out
    # the clock source says (and its stop carries) why the run ended: not "clock source finished"
    assert re.search(
        rf"\[cube\] INFO run stopped at t = [\d.]+ s: interrupted by {signal.Signals(signum).name}\n", out
    ), out
    assert took < 5.0 + 8.0, f"shutdown took {took:.1f} s (sigterm_timeout_s is 5 s)"
    assert [p for p in pids if alive(p)] == [], "orphan node processes"
    assert not list(bus_dir.glob("*.json")), "a node did not remove its manifest (it did not exit cleanly)"
    assert not list(bus_dir.glob("*.pub")), "ipc socket files left behind"


def test_killed_launcher_takes_its_children_along(tmp_path: Path) -> None:
    bus_dir, log = tmp_path / "bus", tmp_path / "launch.log"
    with launched(write(tmp_path, long_graph("realtime")), bus_dir, log) as proc:
        wait_for(lambda: set(node_pids(bus_dir)) == {"cube", "stats"}, 60, "both nodes to start", log)
        pids = list(node_pids(bus_dir).values())
        os.kill(proc.pid, signal.SIGKILL)  # no chance to clean up: the parent-death signal must do it
        proc.wait(timeout=5)
        wait_for(lambda: not any(alive(p) for p in pids), 10, "the orphaned nodes to exit", log)


def test_node_ignoring_sigterm_is_killed_after_its_timeout(tmp_path: Path) -> None:
    extra = f"""  - name: stubborn
    type: {STUBBORN}
    sigterm_timeout_s: 1.0
"""
    bus_dir, log = tmp_path / "bus", tmp_path / "launch.log"
    with launched(write(tmp_path, long_graph("lockstep", extra)), bus_dir, log) as proc:
        wait_for(lambda: "stubborn: ignoring SIGTERM" in text(log), 60, "the stubborn node to arm", log)
        pids = set(node_pids(bus_dir).values()) | set(descendants(proc.pid))
        start = time.monotonic()
        os.kill(proc.pid, signal.SIGTERM)
        code = proc.wait(timeout=30)
        took = time.monotonic() - start
    out = text(log)
    assert code == 128 + signal.SIGTERM, out
    assert "[launch] node 'stubborn' ignored SIGTERM for 1.0 s: killing it" in out
    # the node's own 1 s counted, not the default 5 s: the launcher waits for its children in order, so
    # the others' shutdown (up to about 2 s each on a loaded machine) comes on top
    assert 1.0 <= took < 9.0, f"took {took:.1f} s"
    assert [p for p in pids if alive(p)] == []
    assert not list(bus_dir.glob("*.pub")), "the launcher did not remove the killed node's socket file"


def test_dying_node_is_reported_and_fails_the_launch(tmp_path: Path) -> None:
    extra = f"""  - name: crasher
    type: {CRASHER}
    params: {{after_ticks: 5, exit_code: 3}}
"""
    bus_dir, log = tmp_path / "bus", tmp_path / "launch.log"
    with launched(write(tmp_path, long_graph("lockstep", extra)), bus_dir, log) as proc:
        seen: dict[str, int] = {}  # every node's pid, gathered while they run (the run lasts a moment)

        def both_seen_or_ended() -> bool:
            seen.update(node_pids(bus_dir))
            return set(seen) >= {"cube", "stats"} or proc.poll() is not None

        wait_for(both_seen_or_ended, 60, "the nodes to start", log)
        assert set(seen) >= {"cube", "stats"}, f"the launch ended before both nodes were seen: {seen}"
        pids = set(seen.values())
        code = proc.wait(timeout=30)
    out = text(log)
    assert code == 1, out
    report = out[out.index(f"[launch] node 'crasher' ({CRASHER}) died with exit code 3; stopping the launch.") :]
    first, *rest = report.splitlines()
    assert first.endswith("Last lines:")
    tail = [line.strip() for line in rest[: next(i for i, x in enumerate(rest) if not x.startswith("    "))]]
    # the node's last log lines, in order
    assert tail[-2:] == ["crasher: tick 5 at 40000000 ns", "crasher: giving up with exit code 3"], report
    # the launcher's SIGTERM, or on a loaded machine the cube's own 2 s wait for the dead node's
    # acknowledgement, whichever comes first
    stopped = r"\[cube\] (INFO run stopped at t = [\d.]+ s: interrupted by SIGTERM|.*'crasher' disconnected)"
    assert re.search(stopped, out), out
    assert [p for p in pids if alive(p)] == []


def test_respawned_node_restarts_up_to_max_restarts_then_fails(tmp_path: Path) -> None:
    extra = f"""  - name: crasher
    type: {CRASHER}
    params: {{after_ticks: 5, exit_code: 3}}
    respawn: true
    max_restarts: 2
"""
    bus_dir, log = tmp_path / "bus", tmp_path / "launch.log"
    with launched(write(tmp_path, long_graph("realtime", extra)), bus_dir, log) as proc:
        code = proc.wait(timeout=30)
    out = text(log)
    assert code == 1, out
    deaths = re.findall(r"\[launch\] node 'crasher' \(.*\) died with exit code 3; (.*?)\. Last lines:", out)
    assert deaths == ["respawning (1/2)", "respawning (2/2)", "stopping the launch"], out
    started = re.findall(r"crasher: started as pid (\d+)", out)
    assert len(set(started)) == 3, "three distinct processes: the first and two restarts"


def test_dry_run_starts_no_process(tmp_path: Path) -> None:
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "palpate.cli",
            "launch",
            "--dry-run",
            str(REPO_ROOT / "launch" / "demo_minimal.yaml"),
            "--bus",
            str(tmp_path),
        ],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert proc.returncode == 0, proc.stderr
    assert "  sensors/contacts [ContactSet]: cube -> stats" in proc.stdout
    assert list(tmp_path.iterdir()) == []
