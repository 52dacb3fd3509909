"""Start, watch and stop the processes of a resolved graph.

Children are started with a parent-death signal, so none outlives the launcher even if it is killed.
Ctrl-C or SIGTERM sends SIGTERM to every child, waits up to its `sigterm_timeout_s`, then SIGKILLs.
A child that dies is reported with its exit code and last log lines; the launch then stops and
exits non-zero unless the node is set to respawn (up to `max_restarts`); so does a helper process the
run needs (the recorder, `watch`) that dies before the run ends. A node that ends the run as
a failure (``ctx.request_stop(reason, failed=True)``, exit code EXIT_RUN_FAILED) lets the others stop
in order; the launch then exits 1.
"""

from __future__ import annotations

import contextlib
import ctypes
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import IO

from palpate import jsonio
from palpate.errors import LaunchError
from palpate.launch.graph import Graph, GraphNode
from palpate.launch.placement import CpuPlacement
from palpate.paths import why_not
from palpate.runtime import bus
from palpate.runtime.spec import EXIT_RUN_FAILED, START_TIMEOUT_S, NodeProcessSpec

_PR_SET_PDEATHSIG = 1
_TAIL_LINES = 20


def _die_with_parent() -> None:
    """Run in the child before exec: receive SIGTERM when the launcher dies."""
    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    except OSError:
        pass


#: An external node that has written no manifest this long after the start (seconds) is named once.
MANIFEST_NOTE_S = 10.0


def external_spec_path(bus_dir: str | Path, name: str) -> Path:
    """Where the launcher puts the process spec of external node `name` (docs/runtime.md, "External nodes")."""
    return Path(bus_dir) / "external" / f"{name}.json"


def write_external_spec(bus_dir: str | Path, spec: NodeProcessSpec) -> Path:
    """Write `spec` for the driver that plays external node `spec.name` (atomically: write, then rename).

    The spec may hold the node's CurveZMQ secret key: the folder is 0700 and the file 0600."""
    path = external_spec_path(bus_dir, spec.name)
    path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
    path.parent.chmod(0o700)
    tmp = path.with_suffix(".json.tmp")
    tmp.unlink(missing_ok=True)
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(spec.to_json())
    tmp.replace(path)
    return path


def _place_child(place: CpuPlacement) -> None:
    """Run in the child before exec: die with the parent, take the CPUs and policy of `place` (a
    refusal is reported by the parent, which reads them back)."""
    _die_with_parent()
    with contextlib.suppress(OSError):
        place.apply()


@dataclass
class Child:
    """A running node process and what we keep of its output."""

    node: GraphNode
    spec_path: Path
    proc: subprocess.Popen[bytes] | None = None
    restarts: int = 0
    tail: deque[str] = field(default_factory=lambda: deque(maxlen=_TAIL_LINES))
    pumps: list[threading.Thread] = field(default_factory=list)


def _how(code: int) -> str:
    """How a process ended, from its return code: "signal SIGKILL" or "exit code 2"."""
    return f"signal {signal.Signals(-code).name}" if code < 0 else f"exit code {code}"


class Supervisor:
    """Runs the graph's node processes and reports how they ended."""

    def __init__(
        self,
        graph: Graph,
        process_specs: list[NodeProcessSpec],
        *,
        out: IO[str] | None = None,
        placement: dict[str, CpuPlacement] | None = None,
    ):
        """`placement`: where each node's process runs (palpate.launch.placement; absent: anywhere)."""
        self.graph = graph
        self.placement = placement or {}
        self.out = out or sys.stdout
        # another graph on this bus directory with a node of the same name would take its ipc socket
        self.names = bus.NameClaim(graph.bus_dir, [spec.name for spec in process_specs])
        # the node specs (and any key file) live in a 0700 directory, removed at shutdown: they hold secret keys
        self.run_dir = Path(tempfile.mkdtemp(prefix="palpate-run-"))
        self.children: list[Child] = []
        self.lock = threading.Lock()
        self.stop_signal = 0
        #: Nodes that ended the run as a failure (exit code EXIT_RUN_FAILED): the launch exits 1.
        self.run_failures: list[str] = []
        self.external_specs: list[Path] = []
        self.started_at, self.manifests_checked = 0.0, False  # for the external nodes' manifests
        self.manifests_seen: set[str] = set()  # external nodes whose manifest has been there
        self.driver_pids: dict[str, int] = {}  # external node -> the pid its manifest named first
        self.second_drivers: set[str] = set()  # external nodes said to have two drivers
        #: Processes the run needs besides its nodes (the recorder), by name; started and stopped by the caller.
        self.helpers: dict[str, subprocess.Popen[bytes]] = {}
        #: Those of them whose death stopped the launch (said already).
        self.helpers_died: set[str] = set()
        for spec in process_specs:
            node = graph.by_name[spec.name]
            if node.external:  # not started here: its driver reads what the launcher would have passed it
                self.external_specs.append(write_external_spec(graph.bus_dir, spec))
                continue
            path = self.run_dir / f"{spec.name}.json"
            path.write_text(spec.to_json())
            self.children.append(Child(node=node, spec_path=path))

    def watch(self, name: str, proc: subprocess.Popen[bytes]) -> None:
        """Stop the launch should `proc` fail (exit non-zero) while the nodes run."""
        self.helpers[name] = proc

    def write_secret(self, name: str, values: dict[str, str]) -> Path:
        """Write `values` as JSON readable by this user only, in the run directory; returns the path."""
        path = self.run_dir / name
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "w") as f:
            f.write(jsonio.dumps(values))
        return path

    def _start(self, child: Child) -> None:
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        place = self.placement.get(child.node.name)
        try:
            child.proc = subprocess.Popen(
                [sys.executable, "-m", "palpate.runtime.node", str(child.spec_path)],
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                preexec_fn=_die_with_parent if place is None else lambda: _place_child(place),
                env=env,
            )
        except OSError as exc:  # too many open files or processes for this user
            raise LaunchError(f"cannot start node {child.node.name!r}: {why_not(exc)}{bus.limit_hint(exc)}") from exc
        if place is not None:
            self._check_placed(child, place)
        pump = threading.Thread(target=self._pump, args=(child, child.proc), daemon=True)
        pump.start()
        child.pumps.append(pump)

    def _check_placed(self, child: Child, place: CpuPlacement) -> None:
        """Say so when a child did not get its placement (the system refused it): it runs anyway."""
        assert child.proc is not None
        pid = child.proc.pid
        try:
            placed = os.sched_getaffinity(pid) == place.cpus and os.sched_getscheduler(pid) == os.SCHED_BATCH
        except ProcessLookupError:  # it has already exited: its own report follows
            return
        except OSError as exc:
            self._say(f"node {child.node.name!r}: cannot read back its placement ({place}, SCHED_BATCH): {exc}")
            return
        if not placed:
            self._say(
                f"node {child.node.name!r} runs without its placement ({place}, SCHED_BATCH): the system refused it"
            )

    def _pump(self, child: Child, proc: subprocess.Popen[bytes]) -> None:
        assert proc.stdout is not None
        for raw in proc.stdout:
            line = raw.decode(errors="replace").rstrip("\n")
            child.tail.append(line)
            with self.lock:
                print(line if line.startswith("[") else f"[{child.node.name}] {line}", file=self.out, flush=True)

    def run(self, *, on_started: Callable[[], None] | None = None) -> int:
        """Start every child, supervise until the run ends, and return the launch's exit code."""
        previous = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            for child in self.children:
                self._start(child)
            for path in self.external_specs:
                self._say(
                    f"waiting for external node {path.stem!r}: start its driver, which reads {path} "
                    f"(docs/runtime.md, External nodes); the nodes give up after {START_TIMEOUT_S:g} s without it"
                )
            if on_started is not None:
                on_started()
            return self._supervise()
        finally:
            self.shutdown()
            for s, handler in previous.items():
                signal.signal(s, handler)

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        self.stop_signal = signum

    def _note_missing_manifests(self, now: float) -> None:
        """Say once, MANIFEST_NOTE_S after the start, which external nodes have written no manifest: a driver
        not started yet, or one that writes none (then the recorder and `palpate topic` cannot find its
        topics, and a recorded launch waits for it)."""
        if self.manifests_checked:
            return
        for path in self.external_specs:  # a driver of a short run may have come and gone by the note's time
            if path.stem not in self.manifests_seen and bus.Manifest.path(self.graph.bus_dir, path.stem).exists():
                self.manifests_seen.add(path.stem)
        if now - self.started_at < MANIFEST_NOTE_S:
            return
        self.manifests_checked = True
        for path in self.external_specs:
            manifest = bus.Manifest.path(self.graph.bus_dir, path.stem)
            if path.stem not in self.manifests_seen:
                self._say(
                    f"external node {path.stem!r} has written no manifest {manifest} after {MANIFEST_NOTE_S:g} s: its "
                    "driver has not started, or writes none (docs/runtime.md, External nodes, 3. Manifest); the "
                    "recorder and palpate topic find a node's topics there"
                )

    def _note_second_drivers(self) -> None:
        """Say once per external node when its manifest names another live process than the one it named
        first: a second driver took its endpoint over (ipc lets it), and tools find that one from now on."""
        for path in self.external_specs:
            name = path.stem
            try:
                pid = int(json.loads(bus.Manifest.path(self.graph.bus_dir, name).read_text())["pid"])
            except (OSError, ValueError, KeyError, TypeError):
                continue
            first = self.driver_pids.get(name)
            if first is None or not bus.alive(first):  # the live driver (not a dead one's leftover manifest)
                if bus.alive(pid):
                    self.driver_pids[name] = pid
                continue
            if pid != first and name not in self.second_drivers and bus.alive(pid):
                self.second_drivers.add(name)
                self._say(
                    f"two drivers play external node {name!r} (pids {first} and {pid}, both alive): the second took "
                    "its endpoint and manifest over; stop one"
                )

    def _supervise(self) -> int:
        clock = self.graph.clock_source
        self.started_at = time.monotonic()
        checked_drivers_at = 0.0
        while True:
            self._note_missing_manifests(time.monotonic())
            if self.external_specs and time.monotonic() - checked_drivers_at >= 1.0:
                checked_drivers_at = time.monotonic()
                self._note_second_drivers()
            if self.stop_signal:
                self._say(f"received {signal.Signals(self.stop_signal).name}: stopping every node")
                return 128 + self.stop_signal
            for name, proc in self.helpers.items():
                if (code := proc.poll()) not in (None, 0):
                    self._say(f"the {name} died with {_how(code)}; stopping the launch")
                    self.helpers_died.add(name)
                    return 1
            running = 0
            for child in self.children:
                assert child.proc is not None
                code = child.proc.poll()
                if code is None:
                    running += 1
                    continue
                if code == 0:
                    continue
                if code == EXIT_RUN_FAILED:  # an orderly stop, asked for as a failure: the others still close
                    self._note_run_failure(child)
                    continue
                if child.node.respawn and child.restarts < child.node.max_restarts:
                    child.restarts += 1
                    self._report(child, code, f"respawning ({child.restarts}/{child.node.max_restarts})")
                    self._start(child)
                    running += 1
                    continue
                self._report(child, code, "stopping the launch")
                return 1
            if running == 0:
                return 1 if self.run_failures else 0
            clock_done = clock is not None and any(  # finished, or ended the run as a failure
                c.node is clock and c.proc is not None and c.proc.poll() in (0, EXIT_RUN_FAILED) for c in self.children
            )
            if clock_done:
                return self._drain()
            time.sleep(0.05)

    def _drain(self, timeout_s: float = 30.0) -> int:
        """The clock source finished: give the others time to handle the stop and exit."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            codes = [c.proc.poll() for c in self.children if c.proc is not None]
            if all(code is not None for code in codes):
                failed = [c for c in self.children if c.proc is not None and c.proc.returncode not in (0, None)]
                for child in failed:
                    if child.proc is not None and child.proc.returncode == EXIT_RUN_FAILED:
                        self._note_run_failure(child)
                    else:
                        self._report(child, child.proc.returncode if child.proc else -1, "failed at shutdown")
                return 1 if failed or self.run_failures else 0
            time.sleep(0.05)
        late = [c.node.name for c in self.children if c.proc is not None and c.proc.poll() is None]
        self._say(f"nodes still running {timeout_s:.0f} s after the clock source finished: {late}; terminating")
        return 1

    def _note_run_failure(self, child: Child) -> None:
        """Say once that the run failed, naming the first node to end it as a failure (its own log line gives
        the reason; the nodes that received a RunControl 'fail' end so too, and say why in theirs)."""
        if child.node.name in self.run_failures:
            return
        self.run_failures.append(child.node.name)
        if len(self.run_failures) == 1:
            self._say(
                f"node {child.node.name!r} ({child.node.type}) was the first of its nodes to end the run as a failure "
                "(its log line above says why: another node, or an external one, may have caused it); the launch "
                "exits 1"
            )

    def _report(self, child: Child, code: int, action: str) -> None:
        for pump in child.pumps:
            pump.join(timeout=1.0)
        lines = "\n".join(f"    {line}" for line in child.tail) or "    (no output)"
        self._say(
            f"node {child.node.name!r} ({child.node.type}) died with {_how(code)}; {action}. Last lines:\n{lines}"
        )

    def _say(self, text: str) -> None:
        with self.lock:
            print(f"[launch] {text}", file=self.out, flush=True)

    def shutdown(self) -> None:
        """SIGTERM every live child, wait its timeout, SIGKILL what is left, reap all."""
        try:
            self._stop_children()
        finally:
            shutil.rmtree(self.run_dir, ignore_errors=True)
            self.names.release()

    def _stop_children(self) -> None:
        for path in self.external_specs:
            path.unlink(missing_ok=True)
        live = [c for c in self.children if c.proc is not None and c.proc.poll() is None]
        for child in live:
            assert child.proc is not None
            child.proc.send_signal(signal.SIGTERM)
        for child in live:
            assert child.proc is not None
            try:
                child.proc.wait(timeout=child.node.sigterm_timeout_s)
            except subprocess.TimeoutExpired:
                self._say(f"node {child.node.name!r} ignored SIGTERM for {child.node.sigterm_timeout_s} s: killing it")
                child.proc.kill()
                child.proc.wait()
        for child in self.children:
            for pump in child.pumps:
                pump.join(timeout=1.0)
            # a node that exits cleanly removes its socket file; one that was killed cannot
            bus.remove_ipc_file(child.node.endpoint)
