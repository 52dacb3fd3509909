"""Helpers for tests that start real `palpate launch` processes on a private bus directory."""

from __future__ import annotations

import os
import random
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

import psutil

from palpate.paths import REPO_ROOT
from palpate.runtime import bus


def child_env(bus_dir: Path) -> dict[str, str]:
    """Environment for processes that must import `tests.integration.fake_nodes` and use `bus_dir`.

    Temporary files go beside `bus_dir` (the test's own directory): a launcher that a test kills
    cannot remove its run directory.
    """
    path = os.environ.get("PYTHONPATH", "")
    return dict(
        os.environ,
        PYTHONPATH=f"{REPO_ROOT}{os.pathsep}{path}" if path else str(REPO_ROOT),
        PALPATE_BUS=str(bus_dir),
        PYTHONUNBUFFERED="1",
        TMPDIR=str(bus_dir.parent),
    )


@contextmanager
def launched(launch_file: Path, bus_dir: Path, log: Path, *args: str) -> Iterator[subprocess.Popen[bytes]]:
    """`palpate launch LAUNCH_FILE ARGS --bus BUS_DIR` in its own session, output to `log`.

    On exit the whole session is SIGKILLed if anything of it is still alive, so a failing test leaves
    no processes behind.
    """
    with log.open("wb") as out:
        proc = subprocess.Popen(
            [sys.executable, "-m", "palpate.cli", "launch", str(launch_file), *args, "--bus", str(bus_dir)],
            cwd=REPO_ROOT,
            env=child_env(bus_dir),
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        try:
            yield proc
        finally:
            kill_session(proc)


def kill_session(proc: subprocess.Popen[bytes]) -> None:
    """SIGKILL the process group led by `proc` (a process this test started) and reap `proc`."""
    with suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGKILL)
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()


def wait_for(condition: Callable[[], object], timeout_s: float, what: str, log: Path | None = None) -> None:
    """Poll `condition` until it is true, or fail naming `what` (and the log's tail)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return
        time.sleep(0.05)
    tail = "\n".join(log.read_text(errors="replace").splitlines()[-30:]) if log is not None and log.exists() else ""
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}\n{tail}")


def node_pids(bus_dir: Path) -> dict[str, int]:
    """Live node processes by name, from the manifests they write in the bus directory."""
    return {m.node: m.pid for m in bus.read_manifests(bus_dir)}


def alive(pid: int) -> bool:
    """True while `pid` runs (a zombie is not running)."""
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def descendants(pid: int) -> list[int]:
    try:
        return [p.pid for p in psutil.Process(pid).children(recursive=True)]
    except psutil.NoSuchProcess:
        return []


#: Ports handed out by free_port in this test run.
_HANDED_OUT: set[int] = set()


def free_port(host: str = "127.0.0.1") -> int:
    """A port nothing listens on, for a process to bind later: below the kernel's ephemeral range
    (where it picks the ports of outgoing connections, which could take it meanwhile) and not handed
    out before in this run."""
    try:
        ephemeral_low = int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        ephemeral_low = 32768
    low = 10000
    high = max(low + 1000, min(ephemeral_low, 32768))
    rng = random.Random()
    for _ in range(1000):
        port = rng.randrange(low, high)
        if port in _HANDED_OUT:
            continue
        with socket.socket() as s:
            try:
                s.bind((host, port))
            except OSError:
                continue
        _HANDED_OUT.add(port)
        return port
    raise RuntimeError(f"no free port in {low}-{high} on {host}")


def text(log: Path) -> str:
    return log.read_text(errors="replace")
