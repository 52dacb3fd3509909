"""Runs of an evaluation or sweep as tasks on Dask distributed, resumable through ``runs.jsonl``.

One way to run: every run is one Dask task with a stable key (the run key), submitted to

- a local cluster, one single-threaded worker process per core (``--workers N`` for N), when no
  scheduler is named: nothing to set up;
- an existing cluster, ``--scheduler tcp://HOST:PORT`` or ``$PALPATE_SCHEDULER`` (docs/benchmarks.md
  shows how to start one on a few machines and on SLURM).

Every finished run is appended to ``runs.jsonl`` as it finishes (one JSON object a line, its key in
``run_key``; flushed and fsynced), so a killed evaluation loses only the runs in flight; ``--resume``
reads the file and submits only the runs not in it. A run whose worker dies is rescheduled by Dask on
another worker (up to ``distributed.scheduler.allowed-failures`` times); a run that raises is retried
``retries`` times. Both count as retried; a run is written once, whatever the retries (by key).

Files a run needs (meshes) travel through the cluster, not a shared filesystem: ``RunTask.files`` are
read here, sent once each as a task keyed by their SHA-256 (a worker's lost copy is sent again) and
cached on the worker under :func:`palpate.paths.cache_dir` (:func:`local_copy`).

Row fields whose names start with ``_`` go back to the caller but not into ``runs.jsonl`` (large,
non-JSON results such as maps for a plot).
"""

from __future__ import annotations

import argparse
import concurrent.futures
import contextlib
import functools
import hashlib
import json
import logging
import math
import os
import signal
import socket
import sys
import tempfile
import threading
import time
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from palpate import jsonio, locks
from palpate.argtypes import non_negative_int
from palpate.errors import ClusterError, ConfigError
from palpate.paths import CACHE_DIR_ENV, cache_dir, why_not

#: Environment variable naming the scheduler of an existing Dask cluster (tcp://HOST:PORT).
SCHEDULER_ENV = "PALPATE_SCHEDULER"
#: Longest time between two redraws of the progress bar, seconds.
REFRESH_S = 2.0
#: The scheduler is asked for its tasks' state (running, retried, workers) at most this often (seconds)
#: while no run finishes: each ask is an INFO line in an external scheduler's log.
STATE_PERIOD_S = 5.0
#: After this long (seconds) with no worker on the cluster the evaluation says that its runs wait for one
#: (all of an external cluster's workers died, or their batch jobs ended).
NO_WORKER_NOTE_S = 10.0
#: Dask event topic on which a running task says how far it is (``report_progress``).
PROGRESS_TOPIC = "palpate-run-progress"
#: The field of a runs.jsonl line that holds its run key.
KEY_FIELD = "run_key"

Row = dict[str, Any]


@dataclass(frozen=True, kw_only=True)
class ClusterConfig:
    """Where and how runs execute."""

    #: Address of an existing scheduler (tcp://HOST:PORT); empty: start a local cluster.
    scheduler: str = ""
    #: Worker processes of the local cluster (one thread each); 0: one per core.
    local_workers: int = 0
    #: Extra attempts of a run that raises (a worker's death is rescheduled by Dask on its own).
    retries: int = 2
    #: How long to wait for the scheduler to answer.
    connect_timeout_s: float = 20.0
    #: How long to wait for the first worker of an existing cluster.
    worker_timeout_s: float = 300.0
    #: How often the progress bar asks the scheduler what runs.
    poll_s: float = 1.0
    progress: bool = True

    def __post_init__(self) -> None:
        if self.local_workers < 0:
            raise ConfigError(f"--workers must be >= 1 (0: one per core), got {self.local_workers}")
        if self.retries < 0:
            raise ConfigError(f"retries must be >= 0, got {self.retries}")


@dataclass(frozen=True, kw_only=True)
class SharedFile:
    """A file's bytes and their SHA-256, as a worker receives it."""

    name: str
    sha256: str
    data: bytes

    @classmethod
    def read(cls, path: Path) -> SharedFile:
        data = Path(path).read_bytes()
        return cls(name=Path(path).name, sha256=hashlib.sha256(data).hexdigest(), data=data)


def local_copy(shared: SharedFile) -> Path:
    """The file as a path on this machine: ``cache_dir()/files/<sha256><suffix>``, written once."""
    from palpate.paths import cache_dir

    folder = cache_dir() / "files"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / (shared.sha256 + Path(shared.name).suffix.lower())
    if not path.exists():
        tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
        tmp.write_bytes(shared.data)
        os.replace(tmp, path)  # atomic: concurrent workers on one machine write the same bytes
    return path


def file_digest(path: Path) -> str:
    """SHA-256 of a file's bytes (what names it in run keys and on the workers)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def spell_non_finite(row: Mapping[str, Any]) -> Row:
    """``row`` with its non-finite float fields as "inf", "-inf" or "nan": JSON has no such numbers
    (runs.jsonl would hold null, which cannot tell inf from nan); :func:`read_non_finite` undoes it."""
    return {k: (str(v) if isinstance(v, float) and not math.isfinite(v) else v) for k, v in row.items()}


def read_non_finite(row: Mapping[str, Any]) -> Row:
    """The inverse of :func:`spell_non_finite`."""
    return {k: (float(v) if isinstance(v, str) and v in ("inf", "-inf", "nan") else v) for k, v in row.items()}


def run_key(prefix: str, spec: Any) -> str:
    """A stable run key: ``prefix`` and a digest of the run's full description (JSON-able ``spec``),
    so that a run with other settings never passes for a finished one on --resume."""
    digest = hashlib.sha256(jsonio.dumps(spec, sort_keys=True).encode()).hexdigest()[:12]
    return f"{prefix}-{digest}"


@dataclass(frozen=True, kw_only=True)
class RunTask:
    """One run: ``function(*args, *files)`` on a worker, each file given as a :class:`SharedFile`.

    ``function`` must be importable by the workers (a module-level function of palpate) and return a
    dict whose fields not starting with ``_`` are JSON-able.
    """

    key: str
    function: Callable[..., Row]
    args: tuple[Any, ...] = ()
    files: tuple[Path, ...] = ()
    #: Short name in the progress bar.
    label: str = ""


@dataclass
class Outcome:
    """What a call of :func:`run_tasks` did."""

    rows: dict[str, Row] = field(default_factory=dict)
    resumed: int = 0
    retried: int = 0
    failed: dict[str, str] = field(default_factory=dict)
    workers: int = 0
    wall_s: float = 0.0
    #: The file the runs are kept in (its name is said in ``summary``).
    log_name: str = "runs.jsonl"

    def ordered(self, tasks: Sequence[RunTask]) -> list[Row]:
        """The finished rows in the order of ``tasks`` (failed runs left out)."""
        return [self.rows[t.key] for t in tasks if t.key in self.rows]

    def runs_per_hour_per_worker(self) -> float:
        """Throughput of this call: runs it finished (not resumed) per hour of wall time per worker,
        cluster start-up included."""
        ran = len(self.rows) - self.resumed
        return 3600.0 * ran / self.wall_s / max(1, self.workers) if self.wall_s > 0 else 0.0

    def summary(self) -> str:
        errors = sum(1 for row in self.rows.values() if "error" in row)
        cluster = (  # when every run came from the file, no cluster was started
            f", {self.workers} Dask worker(s), {self.runs_per_hour_per_worker():.0f} runs/hour/worker"
            if self.workers
            else ""
        )
        return (
            f"{len(self.rows)} runs done ({self.resumed} from {self.log_name}"
            + (f"; {errors} ended with an error, which --resume runs again" if errors else "")
            + f"), {len(self.failed)} failed, {self.retried} retried{cluster}"
        )


# --- runs.jsonl ------------------------------------------------------------------------------------------
def _unused(path: Path) -> Path:
    """`path`, or `path`.2, `path`.3, ... whichever does not exist yet."""
    candidate, number = path, 1
    while candidate.exists():
        number += 1
        candidate = path.with_name(f"{path.name}.{number}")
    return candidate


@contextlib.contextmanager
def _interrupts_held() -> Iterator[None]:
    """SIGINT and SIGTERM held back until the block ends, then raised again (in the main thread; elsewhere
    nothing is held): a Ctrl-C or a scheduler's SIGTERM between writing a run and counting it said 'no run
    of it finished' of a file that held one. Python-level handlers, not a blocked signal mask: another
    thread (the Dask client's) takes a signal the main thread blocks, and Python raises it in the main
    thread all the same."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending: list[int] = []

    def hold(signum: int, frame: object) -> None:
        pending.append(signum)

    previous = {signum: signal.signal(signum, hold) for signum in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for held, handler in previous.items():
            signal.signal(held, signal.SIG_DFL if handler is None else handler)  # None: not set from Python
        for arrived in dict.fromkeys(pending):
            signal.raise_signal(arrived)  # through the handler the block had replaced


def _lock_for(path: Path) -> IO[str]:
    """An exclusive lock on ``path`` (its ``.lock`` file beside it, ``palpate.locks``), held while the returned
    file is open; ConfigError naming the holder when another evaluation has it (two clients resuming one
    folder wrote every run twice)."""
    lock_path = path.with_name(path.name + ".lock")
    try:
        return locks.hold(lock_path)
    except OSError as exc:
        raise ConfigError(
            f"cannot write {lock_path} ({why_not(exc)}); give --out a folder you can write, with room on its disk"
        ) from exc
    except locks.LockHeldError as held:
        raise ConfigError(
            f"{path} is being written by another evaluation (pid {held.holder}, {lock_path}); wait for it to end, "
            "or give this one another --out"
        ) from None


class RunLog:
    """``runs.jsonl``: one finished run a line, appended as it finishes, each key at most once.

    ``resume=False`` starts the file afresh when the first run finishes, keeping an earlier file as
    ``runs.jsonl.previous`` (``.previous.2``, ... when that is taken: an evaluation that never gets going,
    a wrong --scheduler, or a second one into the same folder loses nothing), and says so on stderr;
    ``resume=True`` keeps its runs (:attr:`rows`) and drops a last line cut off by a kill.
    """

    def __init__(self, path: Path, *, resume: bool) -> None:
        self.path = Path(path)
        self.rows: dict[str, Row] = {}
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = _lock_for(self.path)
        try:
            self._read(resume)
        except BaseException:
            self._lock.close()
            raise

    def _read(self, resume: bool) -> None:
        """The runs of a resumed file (``rows``), and the file opened for appending."""
        if resume and self.path.exists():
            lines = self.path.read_text().splitlines()
            kept = []
            for number, row in read_rows(self.path, hint="remove the line or run without --resume"):
                if KEY_FIELD not in row:
                    raise ConfigError(f"{self.path}:{number} has no {KEY_FIELD!r}; run without --resume")
                key = str(row.pop(KEY_FIELD))
                if "error" not in row and key not in self.rows:  # an error runs again; a repeated run is kept once
                    kept.append(lines[number - 1])
                    self.rows[key] = row
            if len(kept) < sum(1 for text in lines if text.strip()):  # no cut line, no error rows
                partial = self.path.with_name(self.path.name + ".partial")
                partial.write_text("".join(f"{text}\n" for text in kept))
                partial.replace(self.path)  # a kill meanwhile leaves the file as it was
        self._file: IO[str] | None = self.path.open("a") if resume else None
        if not resume and self.path.exists() and self.path.stat().st_size:
            print(
                f"note: {self.path} holds runs of an earlier evaluation; they move to {self.path.name}.previous "
                "(or .previous.2, ...) when this one's first run finishes (--resume goes on from them instead)",
                file=sys.stderr,
            )

    @property
    def started(self) -> bool:
        """Whether the file holds this evaluation's runs (resumed, or a run finished since a fresh start)."""
        return self._file is not None

    def append(self, key: str, row: Mapping[str, Any]) -> Row | None:
        """Write one finished run (flush + fsync) and return it as --resume will read it back (strict
        JSON: tuples as lists, non-finite floats as None), plus its ``_`` fields; None, and nothing
        written, if the key is there already."""
        if key in self.rows:
            return None
        if self._file is None:  # the first run of a fresh start
            if self.path.exists():
                self.path.replace(_unused(self.path.with_name(self.path.name + ".previous")))
            self._file = self.path.open("a")
        text = jsonio.dumps({KEY_FIELD: key, **{k: v for k, v in row.items() if not k.startswith("_")}})
        stored: Row = json.loads(text)
        del stored[KEY_FIELD]
        stored.update((k, v) for k, v in row.items() if k.startswith("_"))
        with _interrupts_held():  # written and counted, or neither: Ctrl-C's note counts the rows
            try:
                self._file.write(text + "\n")
                self._file.flush()
                os.fsync(self._file.fileno())
            except OSError as exc:  # a full disk: what is in the file stays; --resume leaves out a cut line
                raise ClusterError(
                    f"cannot write {self.path} ({why_not(exc)}): its {len(self.rows)} run(s) written before are "
                    "kept; make room (or copy the folder where there is some) and run again with --resume"
                ) from exc
            self.rows[key] = stored
        return stored

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
        self._lock.close()  # releases the lock; the file stays (``palpate.locks``)

    def __enter__(self) -> RunLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def output_folder(path: Path) -> Path:
    """``--out``, made if missing; ConfigError, before any run, when it is a file, lies below one, or
    cannot be written (a read-only folder failed after the first run, with a traceback)."""
    if path.exists() and not path.is_dir():
        raise ConfigError(f"--out {str(path)!r} is a file; give a folder for the runs, tables and plots")
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as exc:
        raise ConfigError(f"--out {str(path)!r}: cannot write there ({why_not(exc)}); give another folder") from None
    return path


def read_rows(path: Path, *, hint: str) -> list[tuple[int, Row]]:
    """The runs of a ``runs.jsonl`` file with their line numbers; a last line cut off by a kill is left
    out (with a warning), any other line that is not a JSON object is a ConfigError naming it (and
    ``hint``)."""
    lines = Path(path).read_text().splitlines(keepends=True)
    rows = []
    for number, text in enumerate(lines, 1):
        if not text.strip():
            continue
        try:
            row = json.loads(text)
        except json.JSONDecodeError as exc:
            if number == len(lines) and not text.endswith("\n"):
                print(f"{path}:{number} is cut off (the last write was interrupted); left out", file=sys.stderr)
                continue
            raise ConfigError(f"{path}:{number} is not JSON ({exc}); {hint}") from exc
        if not isinstance(row, dict):
            raise ConfigError(f"{path}:{number} is not a run (a JSON object); {hint}")
        rows.append((number, row))
    return rows


# --- the cluster -----------------------------------------------------------------------------------------
def add_arguments(parser: argparse.ArgumentParser, runs_file: str = "runs.jsonl") -> None:
    """--scheduler, --workers and --resume (of OUT/`runs_file`) of every command that runs on Dask."""
    parser.add_argument(
        "--scheduler",
        metavar="tcp://HOST:PORT",
        default=None,
        help=f"Dask scheduler of an existing cluster (default ${SCHEDULER_ENV}; none: a local cluster)",
    )
    parser.add_argument(
        "--workers",
        type=non_negative_int,
        default=0,
        help="worker processes of the local cluster (default, or 0: one per core)",
    )
    parser.add_argument("--resume", action="store_true", help=f"keep the runs already in OUT/{runs_file}, run the rest")


def config_from_args(args: argparse.Namespace, **changes: Any) -> ClusterConfig:
    """ClusterConfig of --scheduler (else $PALPATE_SCHEDULER) and --workers."""
    scheduler = args.scheduler if args.scheduler is not None else os.environ.get(SCHEDULER_ENV, "")
    if scheduler and args.workers:
        raise ConfigError(f"--workers {args.workers} sizes a local cluster; leave it out with --scheduler {scheduler}")
    if scheduler:
        _check_address(scheduler)
    return ClusterConfig(scheduler=scheduler, local_workers=args.workers, **changes)


def _check_address(address: str) -> None:
    """ConfigError unless `address` is a Dask scheduler address (tcp://host:port, tls://host:port or
    host:port); a malformed one made the client raise a ValueError and hang 40 s at exit."""
    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        protocol, location = parse_address(address)
        if protocol not in ("tcp", "tls", "ucx"):
            raise ValueError(f"protocol {protocol!r}")
        parse_host_port(location)
    except ValueError as exc:
        raise ConfigError(
            f"--scheduler {address!r} is not a Dask scheduler address ({exc}); give tcp://HOST:PORT "
            "(`dask scheduler` prints it)"
        ) from exc


def describe(config: ClusterConfig) -> str:
    """Where runs go, for the first line of a command's output."""
    if config.scheduler:
        return f"Dask scheduler {config.scheduler}"
    return f"local Dask cluster, {config.local_workers or os.cpu_count() or 1} worker(s)"


#: Dask starts its workers with MALLOC_TRIM_THRESHOLD_=65536 (to hand freed memory back to the OS), which
#: turns off glibc's adaptive mmap threshold: every array above 128 KiB is then mapped and unmapped
#: afresh, and its pages faulted in again. A FastSLAM update of 100 particles took 2.2 times as long
#: (14.5 against 6.4 ms, most of it system time); the local cluster's workers keep glibc's default.
MALLOC_TRIM_KEY = "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_"


def check_scheduler(address: str, timeout_s: float) -> None:
    """Ask what listens at ``address`` who it is (Dask's ``identity`` call), within ``timeout_s``.

    Raises ClusterError naming what answers unless it is a Dask scheduler: ``Client()`` waited for ever
    on a port where something else listens (an HTTP server, a dashboard) and then spent 40 s in its own
    ``__del__``, and took a worker's address for a scheduler's.
    """
    import asyncio

    from distributed.comm import connect as open_comm
    from distributed.comm.core import FatalCommClosedError
    from distributed.security import Security

    reached = False
    limit_s = timeout_s + min(timeout_s, 5.0)  # Dask's connect retries for timeout_s and then says why

    async def identity() -> object:
        nonlocal reached
        comm = await open_comm(address, timeout=timeout_s, **Security().get_connection_args("client"))
        reached = True
        try:
            await comm.write({"op": "identity", "reply": True})
            return await comm.read()
        finally:
            comm.abort()

    def ask() -> object:
        return asyncio.run(asyncio.wait_for(identity(), limit_s))

    try:
        try:
            asyncio.get_running_loop()
        except RuntimeError:  # no event loop in this thread (a command): ask here
            reply = ask()
        else:  # called from a running loop (a notebook): asyncio.run needs a thread of its own
            with concurrent.futures.ThreadPoolExecutor(1) as pool:
                reply = pool.submit(ask).result()
    except FatalCommClosedError as exc:  # Dask's TLS handshake failed: a certificate, not the address
        raise _insecure(address, exc) from exc
    except (OSError, TimeoutError) as exc:
        if not (reached or _listening(address)):
            raise _unreachable(address, timeout_s, exc) from exc
        said = "no answer" if isinstance(exc, TimeoutError) else f"{type(exc).__name__}: {exc}"
        stage = "to Dask's identity call" if reached else "to Dask's handshake"
        raise _no_scheduler(address, f"{said} {stage} within {limit_s:g} s") from exc
    except (TypeError, RuntimeError) as exc:
        if not reached:  # raised before a byte went out: Dask's security settings do not fit the address
            raise _insecure(address, exc) from exc
        raise _no_scheduler(address, f"{type(exc).__name__}: {exc}") from exc
    except (MemoryError, ValueError) as exc:  # another protocol's bytes read as Dask's frames
        raise _no_scheduler(address, f"{type(exc).__name__}: {exc}") from exc
    kind = reply.get("type") if isinstance(reply, dict) else None
    if kind in ("Worker", "Nanny"):
        raise ClusterError(f"what answers at {address} is a Dask {kind.lower()}, not the scheduler; {_GIVE_SCHEDULER}")
    if kind != "Scheduler":
        raise _no_scheduler(address, f"its identity: {str(reply)[:200]}")


_GIVE_SCHEDULER = "give the address `dask scheduler` prints as 'Scheduler at' (its dashboard's port is another)"


def _unreachable(address: str, timeout_s: float, exc: BaseException) -> ClusterError:
    return ClusterError(
        f"cannot reach the Dask scheduler at {address} within {timeout_s:g} s ({str(exc) or 'no connection'}); "
        f"start one with `dask scheduler` (docs/benchmarks.md) or leave out --scheduler and ${SCHEDULER_ENV} to run "
        "on a local cluster"
    )


def _insecure(address: str, exc: BaseException) -> ClusterError:
    return ClusterError(
        f"cannot connect to the Dask scheduler at {address}: Dask's security settings do not fit it "
        f"({type(exc).__name__}: {exc}); check the TLS keys of your Dask configuration (distributed.comm.tls.*, "
        "distributed.comm.require-encryption) and the address's scheme (tls:// or tcp://)"
    )


def _no_scheduler(address: str, why: str) -> ClusterError:
    return ClusterError(f"what answers at {address} is no Dask scheduler ({why}); {_GIVE_SCHEDULER}")


def _listening(address: str) -> bool:
    """Whether a TCP connection to ``address`` opens (something listens there, Dask or not)."""
    from distributed.comm import get_address_host_port

    try:
        host, port = get_address_host_port(address)
        with socket.create_connection((host, port), timeout=2.0):
            return True
    except (OSError, ValueError):
        return False


@contextlib.contextmanager
def connect(config: ClusterConfig) -> Iterator[Any]:
    """A dask.distributed Client: to ``config.scheduler``, or to a local cluster started (and stopped) here."""
    import dask
    from distributed import Client, LocalCluster

    # Dask's INFO lines (scheduler and workers starting) would interleave with the progress bar
    logging.getLogger("distributed").setLevel(logging.WARNING if config.scheduler else logging.ERROR)
    if config.scheduler:
        check_scheduler(config.scheduler, config.connect_timeout_s)
        try:
            client = Client(config.scheduler, timeout=config.connect_timeout_s, set_as_default=False)
        except (OSError, TimeoutError) as exc:
            raise _unreachable(config.scheduler, config.connect_timeout_s, exc) from exc
        except (MemoryError, ValueError) as exc:  # another protocol's bytes read as Dask's frame lengths
            raise _no_scheduler(config.scheduler, f"{type(exc).__name__}: {exc}") from exc
        try:
            if not client.scheduler_info().get("workers"):
                print(
                    f"waiting for a Dask worker to join {config.scheduler} (up to {config.worker_timeout_s:g} s; "
                    f"start one with `dask worker {config.scheduler}`)",
                    file=sys.stderr,
                )
            try:
                client.wait_for_workers(1, timeout=config.worker_timeout_s)
            except TimeoutError as exc:
                raise ClusterError(
                    f"no Dask worker joined the scheduler at {config.scheduler} within {config.worker_timeout_s:g} s;"
                    f" start some with `dask worker {config.scheduler}`"
                ) from exc
            yield client
        finally:
            client.close()
        return
    # One BLAS thread per worker (the workers already fill the cores) is Dask's own pre-spawn default,
    # unless this process's environment sets a count; the nanny writes those variables into this
    # process's environment too, before it spawns a worker.
    with (
        dask.config.set({MALLOC_TRIM_KEY: None}),
        LocalCluster(
            n_workers=config.local_workers or os.cpu_count() or 1,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address=":0",
            # CRITICAL, not ERROR: a worker whose heartbeat races the scheduler's shutdown logs a traceback
            # at ERROR after a successful evaluation (dask/distributed#7192); a run's own failure reaches
            # the client (Outcome.failed) and is printed there
            silence_logs=logging.CRITICAL,
        ) as cluster,
        Client(cluster, set_as_default=False) as client,
    ):
        yield client


def dashboard(client: Any) -> str:
    """The dashboard's address, or "" when the scheduler serves none (bokeh not installed)."""
    services = client.scheduler_info().get("services", {})
    return str(client.dashboard_link) if "dashboard" in services else ""


def _scheduler_state(keys: Sequence[str], retries: int, dask_scheduler: Any = None) -> dict[str, Any]:
    """On the scheduler: how many of ``keys`` are processing, and each key's extra attempts so far
    (worker deaths while it ran + retries after an exception)."""
    threads = sum(ws.nthreads for ws in dask_scheduler.workers.values())
    running, attempts = 0, {}
    for key in keys:
        ts = dask_scheduler.tasks.get(key)
        if ts is None:
            continue
        running += ts.state == "processing"
        extra = int(ts.suspicious) + max(0, retries - int(ts.retries or 0))
        if extra:
            attempts[key] = extra
    # tasks a worker holds include those queued behind the one it executes
    return {"running": min(running, threads), "attempts": attempts, "workers": len(dask_scheduler.workers)}


class WorkerWatch:
    """Says once per outage that the cluster has had no worker for NO_WORKER_NOTE_S (the runs then wait
    in silence), and again when one is back."""

    def __init__(self, scheduler: str) -> None:
        self.scheduler = scheduler
        self.since: float | None = None  # when the cluster was last seen without a worker
        self.told = False

    def note(self, workers: int, now_s: float) -> str:
        """What to say, given the cluster's worker count at monotonic time ``now_s`` ('' for nothing)."""
        if workers:
            back = self.told
            self.since, self.told = None, False
            return f"a Dask worker is back ({workers} now); the runs go on" if back else ""
        if self.since is None:
            self.since = now_s
        if self.told or now_s - self.since < NO_WORKER_NOTE_S:
            return ""
        self.told = True
        start = "the local cluster restarts them"
        if self.scheduler:
            start = f"start one with `dask worker {self.scheduler}`"
        return (
            f"no Dask worker on the cluster for {now_s - self.since:.0f} s: the runs wait for one ({start}; "
            "Ctrl-C keeps the finished runs for --resume)"
        )


@contextlib.contextmanager
def terminate_as_interrupt() -> Iterator[None]:
    """SIGTERM (a batch scheduler's, ``timeout``'s, ``kill``'s) ends the evaluation as Ctrl-C does: the
    finished runs stay in runs.jsonl and the command says how to go on (it ended with no word before)."""

    def interrupt(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt(f"signal {signum}")

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def run_tasks(
    tasks: Sequence[RunTask],
    log: RunLog,
    config: ClusterConfig,
    foreign_rows: str = (
        "which --from-runs then refuses where two hold the same run: give each setting an --out of its own"
    ),
) -> Outcome:
    """Run every task whose key is not in ``log`` on the cluster of ``config``, writing each finished
    row to ``log`` as it finishes; one progress bar (done, running, failed, retried) over all tasks.

    Tasks must have distinct keys. A task that still fails after its retries (or whose workers keep
    dying) is reported in ``Outcome.failed`` and left out of ``log``, so that --resume runs it again.
    ``foreign_rows`` ends the note on rows of ``log`` that are no task's ("" for a command whose file
    holds rows of several settings by design, a sweep's).
    """
    from distributed import as_completed
    from distributed.comm.core import CommClosedError
    from tqdm import tqdm

    keys = [t.key for t in tasks]
    if len(set(keys)) != len(keys):
        raise ConfigError("two runs share a run key; every run needs its own (object, strategy, run, settings)")
    start = time.perf_counter()
    outcome = Outcome(rows={t.key: log.rows[t.key] for t in tasks if t.key in log.rows}, log_name=log.path.name)
    outcome.resumed = len(outcome.rows)
    foreign = len(log.rows) - outcome.resumed
    if foreign:  # rows of other settings (a --set changed), objects or strategies: kept, not this command's
        runs = "1 run" if foreign == 1 else f"{foreign} runs"
        print(
            f"note: {runs} in {log.path} {'is' if foreign == 1 else 'are'} no run of this "
            f"command (other settings, objects or strategies); kept, while its own runs join the file"
            + (f", {foreign_rows}" if foreign_rows else ""),
            file=sys.stderr,
        )
    todo = [t for t in tasks if t.key not in log.rows]
    if not todo:
        return outcome
    bar = tqdm(total=len(tasks), initial=outcome.resumed, unit="run", smoothing=0.0, disable=not config.progress)
    latest: dict[str, str] = {}  # key -> its newest progress, newest last
    try:
        with terminate_as_interrupt(), connect(config) as client:
            outcome.workers = len(client.scheduler_info().get("workers", {}))
            link = dashboard(client)
            where = describe(config) + (f"; dashboard {link}" if link else "")
            print(f"{len(todo)} run(s) on {where}", file=sys.stderr)
            shared = _share_files(client, todo)
            digest = code_digest()

            def submit(t: RunTask, key: str, **where: Any) -> Any:
                args = (*t.args, *(shared[p] for p in t.files))
                return client.submit(
                    run_checked, digest, t.function, *args, key=key, retries=config.retries, pure=False, **where
                )

            pending = {submit(t, t.key): t for t in todo}
            unfit: set[str] = set()  # workers that cannot run palpate's runs (WorkerUnfitError)
            moved: dict[str, int] = {}  # run key -> times given to other workers
            attempts: dict[str, int] = {}
            shown: tuple[Any, ...] = ()
            watch = WorkerWatch(config.scheduler or "")

            def note(event: tuple[float, Any]) -> None:
                msg = event[1]
                if isinstance(msg, dict) and "key" in msg:
                    latest.pop(str(msg["key"]), None)
                    latest[str(msg["key"])] = str(msg.get("text", ""))

            client.subscribe_topic(PROGRESS_TOPIC, note)
            queue = as_completed(list(pending), loop=client.loop)
            state: dict[str, Any] = {}
            asked_at = -math.inf
            while not queue.is_empty():
                batch = queue.next_batch(block=False)
                if batch or time.monotonic() - asked_at >= STATE_PERIOD_S:  # each ask is a line in its log
                    keys = [str(f.key) for f in pending]
                    state = client.run_on_scheduler(_scheduler_state, keys, config.retries)
                    asked_at = time.monotonic()
                attempts.update(state["attempts"])
                if said := watch.note(state.get("workers", 1), time.monotonic()):  # (an older palpate there)
                    tqdm.write(said, file=sys.stderr)
                for future in batch:
                    task = pending.pop(future)
                    if future.status in ("lost", "pending"):
                        # it finished, then its result died with its worker before this loop read it:
                        # the scheduler computes it again for the future still held here
                        pending[future] = task
                        queue.add(future)
                        continue
                    if future.status == "finished":
                        row = log.append(task.key, future.result())
                        if row is not None:
                            outcome.rows[task.key] = row
                    elif future.status == "cancelled":  # the scheduler forgot it (restarted, or lost)
                        outcome.failed[task.key] = f"{task.label or task.key}: cancelled by the scheduler"
                    else:
                        exc = future.exception()
                        spare = _spare_workers(client, unfit, exc)
                        if spare and moved.get(task.key, 0) < MAX_MOVES:  # the run elsewhere: no fault of its own
                            moved[task.key] = moved.get(task.key, 0) + 1
                            # loose: should those workers all leave, any (a newcomer) may take it
                            retry = submit(
                                task, f"{task.key}-moved-{moved[task.key]}", workers=spare, allow_other_workers=True
                            )
                            pending[retry] = task
                            queue.add(retry)
                            future.release()
                            continue
                        outcome.failed[task.key] = f"{task.label or task.key}: {type(exc).__name__}: {exc}"
                    future.release()
                    bar.update(1)
                outcome.retried = len(attempts)
                running = {t.key: t for t in pending.values()}
                status = (
                    len(outcome.rows),
                    state["running"],
                    len(outcome.failed),
                    outcome.retried,
                    _progress_text(latest, running),
                )
                if status != shown:
                    shown = status
                    bar.set_postfix_str("done {}, running {}, failed {}, retried {}{}".format(*status))
                elif not bar.disable and time.time() - bar.last_print_t > REFRESH_S:
                    bar.refresh()  # the elapsed time moves while long runs are in flight
                if not batch:
                    time.sleep(config.poll_s)
    except KeyboardInterrupt:
        bar.close()
        print(f"\ninterrupted: {_kept(tasks, log)}", file=sys.stderr)
        for line in lost_in_flight(latest, outcome, todo):
            print(line, file=sys.stderr)
        raise
    except (CommClosedError, ConnectionError) as exc:  # the scheduler went away mid-run: the finished runs stay
        bar.close()
        for line in lost_in_flight(latest, outcome, todo):
            print(line, file=sys.stderr)
        raise ClusterError(
            f"lost the Dask scheduler {config.scheduler or '(local cluster)'} ({type(exc).__name__}: {exc}); "
            f"{_kept(tasks, log)} (start the cluster again first)"
        ) from exc
    finally:
        bar.close()
    outcome.wall_s = time.perf_counter() - start
    return outcome


#: Most times one run is given to other workers after failing on unfit ones (``run_tasks``).
MAX_MOVES = 10


def _spare_workers(client: Any, unfit: set[str], exc: BaseException | None) -> list[str]:
    """After a run failed on a worker that cannot run palpate's runs (WorkerUnfitError): that worker joins
    ``unfit`` (said once) and the workers of the cluster that are not, to give the run to; [] after any
    other error, or when no other worker is left."""
    if not isinstance(exc, WorkerUnfitError):
        return []
    workers = [str(w) for w in client.scheduler_info().get("workers", {}) if w not in unfit and w != exc.worker]
    if exc.worker not in unfit:
        unfit.add(exc.worker)
        from tqdm import tqdm

        where = "its runs go to the other workers" if workers else "no other worker is left"
        tqdm.write(f"{exc}; {where}", file=sys.stderr)
    return workers


def _kept(tasks: Sequence[RunTask], log: RunLog) -> str:
    """What an evaluation that stops early keeps, and how to go on."""
    finished = sum(1 for t in tasks if t.key in log.rows)  # a resumed file may hold another command's runs
    if log.started and finished:
        return (
            f"{finished} of its {len(tasks)} run(s) are finished in {log.path}; the same command with --resume "
            "goes on from them"
        )
    if log.path.exists():
        return f"no run of it finished; {log.path} is as it was"
    return "no run of it finished; nothing was written"  # (it said the file was as it was)


class WorkerUnfitError(RuntimeError):
    """A worker that cannot run palpate's runs as the client would (other code, a missing package, no cache
    directory): a failure of the worker, not the run's own error, so no error row is written; ``run_tasks``
    gives the run to the other workers, and reports it failed, naming the worker, when none is left."""

    def __init__(self, message: str, worker: str) -> None:
        super().__init__(message, worker)  # both in args: the exception crosses from the worker pickled
        self.message, self.worker = message, worker

    def __str__(self) -> str:
        return self.message


@functools.lru_cache(maxsize=1)
def code_digest() -> str:
    """SHA-256 of the code a run depends on: palpate's packages' Python files and launch files (a worker on
    another commit, or with an edit, gave other results under the same run keys without a word)."""
    import palpate
    import palpate.launch_files
    import palpate.messages
    import palpate.nodes

    digest = hashlib.sha256()
    for package in (palpate, palpate.nodes, palpate.messages, palpate.launch_files):
        for root in map(Path, package.__path__):
            files = (
                p
                for p in root.rglob("*")
                if p.suffix in (".py", ".yaml") and "__pycache__" not in p.parts and p.is_file()
            )
            for path in sorted(files):
                digest.update(f"{package.__name__}/{path.relative_to(root).as_posix()}\0".encode())
                digest.update(path.read_bytes())
    return digest.hexdigest()


@functools.lru_cache(maxsize=1)
def _unfit_because() -> str:
    """Why this process cannot run palpate's runs ("" when it can): a module of a built-in node type
    (``NODE_TYPES``) that does not import (a package missing from the worker's environment), or a cache
    directory it cannot make."""
    import importlib

    from palpate.launch.node_types import NODE_TYPES

    for module in dict.fromkeys(reference.partition(":")[0] for reference in NODE_TYPES.values()):
        try:
            importlib.import_module(module)
        except ImportError as exc:
            return f"cannot import {module} ({exc})"
    try:
        cache_dir()
    except OSError as exc:
        return f"cannot make its cache directory ({type(exc).__name__}: {exc}; ${CACHE_DIR_ENV})"
    return ""


def run_checked(digest: str, function: Callable[..., Row], *args: Any) -> Row:
    """``function(*args)`` on a worker that runs the client's code (``digest``, ``code_digest``) and can run
    palpate; WorkerUnfitError naming the worker otherwise (a worker without mujoco failed 11 of 12 runs in
    milliseconds, each written as the run's own error, none naming it)."""
    why = (
        ""
        if code_digest() == digest
        else (
            f"runs other palpate code than the client (source digest {code_digest()[:12]}, the client's "
            f"{digest[:12]}): give it a checkout at the client's commit (`make setup`)"
        )
    )
    why = why or _unfit_because()
    if why:
        try:
            from distributed import get_worker

            name = get_worker().address
        except (ImportError, ValueError):
            name = f"pid {os.getpid()}"
        raise WorkerUnfitError(f"the Dask worker {name} {why}", name)
    return function(*args)


def lost_in_flight(latest: Mapping[str, str], outcome: Outcome, tasks: Sequence[RunTask]) -> list[str]:
    """A line per run that had said how far it was (``latest``) and neither finished nor failed: what an
    interruption loses."""
    labels = {t.key: t.label or t.key for t in tasks}
    return [
        f"  lost in flight: {labels.get(key, key)}: {text}"
        for key, text in latest.items()
        if key not in outcome.rows and key not in outcome.failed
    ]


def report_progress(text: str) -> None:
    """From a task on a Dask worker: how far it is (``text``, short), shown beside its label in the
    progress bar of :func:`run_tasks`. Outside a Dask task, nothing."""
    try:
        from distributed import get_worker

        worker = get_worker()
        key = worker.get_current_task()
    except (ImportError, ValueError):  # not on a worker
        return
    if key is not None:
        worker.log_event(PROGRESS_TOPIC, {"key": str(key), "text": text})


def _progress_text(latest: Mapping[str, str], running: Mapping[str, RunTask]) -> str:
    """The newest progress of a task still running: '; LABEL: TEXT', or ''."""
    for key, text in reversed(list(latest.items())):  # one snapshot: the client's thread updates `latest`
        if key in running:
            return f"; {running[key].label or key}: {text}"
    return ""


def _share_files(client: Any, tasks: Sequence[RunTask]) -> dict[Path, Any]:
    """Each distinct file of ``tasks`` as one small task keyed by its SHA-256 that returns its
    SharedFile: path -> future. Workers fetch the result from each other; unlike scattered data, a
    task's result lost with its worker is computed again (the bytes are in the task itself)."""
    out = {}
    for path in sorted({p for t in tasks for p in t.files}):
        shared = SharedFile.read(path)
        with warnings.catch_warnings():  # a large mesh is such a task by design: Dask's advice is not the user's
            warnings.filterwarnings("ignore", message="Sending large graph", category=UserWarning)
            out[path] = client.submit(_same, shared, key=f"palpate-file-{shared.sha256}", pure=False)
    return out


def _same(shared: SharedFile) -> SharedFile:
    return shared


def report_failures(outcome: Outcome) -> None:
    """Print the runs that failed for good (they are not in runs.jsonl: --resume runs them again)."""
    for message in outcome.failed.values():
        print(f"run failed: {message}", file=sys.stderr)
    if outcome.failed:
        print(f"{len(outcome.failed)} run(s) failed; --resume runs them again", file=sys.stderr)
