"""palpate.evaluation.dask_runs: runs.jsonl (append once, resume, a cut-off last line), the cluster
options, the error for an unreachable scheduler, and run_tasks on a one-worker local cluster."""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import os
import socket
from pathlib import Path

import pytest

from palpate.errors import ClusterError, ConfigError
from palpate.evaluation import dask_runs
from palpate.evaluation.dask_runs import ClusterConfig, RunLog, RunTask, SharedFile, local_copy, run_key


def lines(path: Path) -> list[dict[str, object]]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def test_a_run_is_written_once_as_strict_json_without_its_private_fields(tmp_path: Path) -> None:
    with RunLog(tmp_path / "runs.jsonl", resume=False) as log:
        stored = log.append("a", {"x": (1, 2), "y": math.nan, "_maps": object()})
        assert stored is not None
        assert stored["x"] == [1, 2] and stored["y"] is None and "_maps" in stored
        assert log.append("a", {"x": 3}) is None
    assert lines(tmp_path / "runs.jsonl") == [{"run_key": "a", "x": [1, 2], "y": None}]


def test_resume_keeps_the_finished_runs_and_drops_a_cut_off_last_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "runs.jsonl"
    path.write_text('{"run_key": "a", "x": 1}\n{"run_key": "b", "x": 2}\n{"run_key": "c", "x"')
    with RunLog(path, resume=True) as log:
        assert log.rows == {"a": {"x": 1}, "b": {"x": 2}}
        log.append("c", {"x": 3})
    assert [r["run_key"] for r in lines(path)] == ["a", "b", "c"]
    previous = path.read_text()
    with RunLog(path, resume=False) as log:  # a fresh start that never finishes a run changes nothing
        assert log.rows == {}
    assert path.read_text() == previous
    with RunLog(path, resume=False) as log:
        log.append("d", {"x": 4})
    assert [r["run_key"] for r in lines(path)] == ["d"]
    assert (tmp_path / "runs.jsonl.previous").read_text() == previous  # kept beside it
    capsys.readouterr()
    with RunLog(path, resume=False) as log:  # a second fresh start keeps both earlier files, and says so
        log.append("e", {"x": 5})
    assert (
        "runs.jsonl holds runs of an earlier evaluation; they move to runs.jsonl.previous (or"
        in capsys.readouterr().err
    )
    assert [r["run_key"] for r in lines(tmp_path / "runs.jsonl.previous.2")] == ["d"]
    assert (tmp_path / "runs.jsonl.previous").read_text() == previous


def test_resume_runs_again_what_ended_with_an_error(tmp_path: Path) -> None:
    """A run that raised a PalpateError is a row with "error"; --resume kept it, never ran it again and
    the evaluation exited 1 for ever (an outside audit)."""
    path = tmp_path / "runs.jsonl"
    path.write_text('{"run_key": "a", "x": 1}\n{"run_key": "b", "error": "MeshError: bad"}\n')
    with RunLog(path, resume=True) as log:
        assert log.rows == {"a": {"x": 1}}
        log.append("b", {"x": 2})
    assert [r["run_key"] for r in lines(path)] == ["a", "b"] and "error" not in lines(path)[1]


def test_resume_refuses_a_broken_line_in_the_middle(tmp_path: Path) -> None:
    path = tmp_path / "runs.jsonl"
    path.write_text('{"run_key": "a"}\nnot json\n{"run_key": "b"}\n')
    with pytest.raises(ConfigError, match=r"runs.jsonl:2"):
        RunLog(path, resume=True)


def test_run_keys_name_the_run_and_change_with_its_settings() -> None:
    assert run_key("explore-ball-igef-0", {"v": 1}) == run_key("explore-ball-igef-0", {"v": 1})
    assert run_key("explore-ball-igef-0", {"v": 1}) != run_key("explore-ball-igef-0", {"v": 2})
    assert run_key("explore-ball-igef-0", {"v": 1}).startswith("explore-ball-igef-0-")


def test_a_shared_file_lands_in_the_cache_under_its_digest(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    source = tmp_path / "mesh.STL"
    source.write_bytes(b"solid x")
    monkeypatch.setenv("PALPATE_CACHE_DIR", str(tmp_path / "cache"))
    shared = SharedFile.read(source)
    copy = local_copy(shared)
    assert copy.name == shared.sha256 + ".stl"
    assert copy.read_bytes() == b"solid x"
    assert local_copy(shared) == copy


def parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    dask_runs.add_arguments(parser)
    return parser.parse_args(argv)


def test_the_scheduler_comes_from_the_option_else_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(dask_runs.SCHEDULER_ENV, "tcp://10.0.0.1:8786")
    assert dask_runs.config_from_args(parse()).scheduler == "tcp://10.0.0.1:8786"
    assert dask_runs.config_from_args(parse("--scheduler", "tcp://h:1")).scheduler == "tcp://h:1"
    monkeypatch.delenv(dask_runs.SCHEDULER_ENV)
    config = dask_runs.config_from_args(parse("--workers", "3"))
    assert (config.scheduler, config.local_workers) == ("", 3)
    with pytest.raises(ConfigError, match="--workers 3"):
        dask_runs.config_from_args(parse("--workers", "3", "--scheduler", "tcp://h:1"))


def test_an_unreachable_scheduler_is_named_in_the_error() -> None:
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    address = f"tcp://127.0.0.1:{port}"
    with (
        pytest.raises(ClusterError, match=f"cannot reach the Dask scheduler at {address}"),
        dask_runs.connect(ClusterConfig(scheduler=address, connect_timeout_s=1.0)),
    ):
        pass


@pytest.mark.slow
def test_run_tasks_skips_finished_runs_retries_and_reports_failures(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "runs.jsonl"
    path.write_text('{"run_key": "done", "x": 0}\n{"run_key": "other-setting", "x": 9}\n')
    tasks = [
        RunTask(key="done", function=dict, args=(5,)),  # would raise: must not run again
        RunTask(key="one", function=dict, args=([("x", 1)],)),
        RunTask(key="two", function=dict, args=([("x", 2)],)),
        RunTask(key="bad", function=dict, args=(7,), label="bad run"),  # TypeError every time
    ]
    config = ClusterConfig(local_workers=1, retries=1, progress=False, poll_s=0.05)
    with RunLog(path, resume=True) as log:
        outcome = dask_runs.run_tasks(tasks, log, config)
    assert outcome.ordered(tasks) == [{"x": 0}, {"x": 1}, {"x": 2}]
    assert outcome.resumed == 1
    assert list(outcome.failed) == ["bad"] and "bad run: TypeError" in outcome.failed["bad"]
    assert outcome.retried == 1
    assert sorted(r["run_key"] for r in lines(path)) == ["done", "one", "other-setting", "two"]
    # an outside walkthrough: a --resume with another --set joined its runs to the others' without a word
    assert "note: 1 run in " in capsys.readouterr().err


def _reports(n: int) -> dict[str, int]:
    dask_runs.report_progress(f"{n} contacts")
    return {"x": n}


@pytest.mark.slow
def test_a_task_on_a_worker_tells_the_client_how_far_it_is() -> None:
    import time

    from distributed import Client, LocalCluster

    events: list[tuple[float, object]] = []
    with (
        LocalCluster(n_workers=1, processes=False, threads_per_worker=1, dashboard_address=None) as cluster,
        Client(cluster) as client,
    ):
        client.subscribe_topic(dask_runs.PROGRESS_TOPIC, events.append)
        assert client.submit(_reports, 12, key="run-a").result() == {"x": 12}
        deadline = time.monotonic() + 10.0
        while not events and time.monotonic() < deadline:
            time.sleep(0.05)
    assert [(msg["key"], msg["text"]) for _, msg in events] == [("run-a", "12 contacts")]  # type: ignore[index]
    assert _reports(3) == {"x": 3}  # outside a Dask task it reports nothing and does not fail


def test_a_large_mesh_is_shared_without_dasks_large_graph_warning(tmp_path: Path) -> None:
    """An outside walkthrough: a 327k-face mesh printed distributed's "Sending large graph" advice, which a
    user cannot act on (the file's bytes are in its task by design, so a lost worker's copy is remade)."""
    import os
    import warnings

    from distributed import Client, LocalCluster

    mesh = tmp_path / "fine.stl"
    mesh.write_bytes(os.urandom(12 * 2**20))

    class Task:
        files = (mesh,)

    with (
        LocalCluster(n_workers=1, processes=False, threads_per_worker=1, dashboard_address=None) as cluster,
        Client(cluster) as client,
        warnings.catch_warnings(),
    ):
        warnings.simplefilter("error", UserWarning)
        shared = dask_runs._share_files(client, [Task()])  # type: ignore[list-item]
        assert shared[mesh].result().data == mesh.read_bytes()


def test_the_bar_shows_the_newest_progress_of_a_run_still_running() -> None:
    running = {"a": RunTask(key="a", function=dict, label="cup igef run 0"), "c": RunTask(key="c", function=dict)}
    latest = {"a": "10 contacts", "b": "99 contacts", "c": "5 contacts"}  # b has finished
    assert dask_runs._progress_text(latest, running) == "; c: 5 contacts"
    del running["c"]
    assert dask_runs._progress_text(latest, running) == "; cup igef run 0: 10 contacts"
    assert dask_runs._progress_text(latest, {}) == ""


def test_an_interruption_names_the_runs_it_loses_with_how_far_they_had_come() -> None:
    tasks = [RunTask(key=k, function=dict, label=f"cup {k}") for k in ("a", "b", "c", "d")]
    outcome = dask_runs.Outcome(rows={"a": {"x": 1}}, failed={"b": "b: TypeError"})
    latest = {"a": "900 contacts", "b": "5 contacts", "c": "1978 contacts, 25.9 % covered, 41.0 m"}
    assert dask_runs.lost_in_flight(latest, outcome, tasks) == [
        "  lost in flight: cup c: 1978 contacts, 25.9 % covered, 41.0 m"  # d had said nothing yet
    ]


def test_two_runs_with_one_key_are_refused(tmp_path: Path) -> None:
    with RunLog(tmp_path / "runs.jsonl", resume=False) as log, pytest.raises(ConfigError, match="run key"):
        dask_runs.run_tasks([RunTask(key="a", function=dict), RunTask(key="a", function=dict)], log, ClusterConfig())


def test_a_malformed_scheduler_address_or_an_out_that_is_a_file_is_refused_by_name(tmp_path: Path) -> None:
    """An outside audit: `--scheduler notanaddress` was a ValueError traceback and a 40 s hang; `--out` naming
    a file a FileExistsError traceback."""
    from palpate.evaluation.dask_runs import config_from_args, output_folder

    for address in ("notanaddress", "http://127.0.0.1:8786", "tcp://host"):
        with pytest.raises(ConfigError, match="is not a Dask scheduler address"):
            config_from_args(argparse.Namespace(scheduler=address, workers=0))
    assert config_from_args(argparse.Namespace(scheduler="tcp://127.0.0.1:8786", workers=0)).scheduler
    (tmp_path / "file").write_text("")
    with pytest.raises(ConfigError, match="is a file; give a folder"):
        output_folder(tmp_path / "file")
    assert output_folder(tmp_path / "a" / "b").is_dir()
    with pytest.raises(ConfigError, match="file/sub': cannot write there \\(Not a directory\\); give another folder"):
        output_folder(tmp_path / "file" / "sub")  # (an outside walkthrough: a NotADirectoryError traceback)


def test_a_scheduler_without_workers_is_said_at_once_and_then_given_up(capsys: pytest.CaptureFixture[str]) -> None:
    """An outside audit: the bar sat silently at 0/N for up to 300 s before saying anything."""
    from distributed import LocalCluster

    with LocalCluster(n_workers=0, processes=False, dashboard_address=None) as cluster:
        config = ClusterConfig(scheduler=cluster.scheduler_address, worker_timeout_s=1.0)
        with pytest.raises(ClusterError, match="no Dask worker joined"), dask_runs.connect(config):
            pass
    assert f"waiting for a Dask worker to join {cluster.scheduler_address}" in capsys.readouterr().err


def _malloc_trim_threshold() -> str | None:
    import os

    return os.environ.get("MALLOC_TRIM_THRESHOLD_")


def test_the_local_clusters_workers_keep_glibcs_memory_defaults(monkeypatch: pytest.MonkeyPatch) -> None:
    """Dask starts workers with MALLOC_TRIM_THRESHOLD_=65536, which made FastSLAM's updates 2.2 times
    slower (every large array mapped and faulted in afresh); the local cluster leaves it out."""
    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_", raising=False)
    with dask_runs.connect(ClusterConfig(local_workers=1)) as client:
        assert list(client.run(_malloc_trim_threshold).values()) == [None]


def _blas_threads() -> dict[str, str | None]:
    import os

    return {var: os.environ.get(var) for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}


def test_the_local_clusters_workers_get_one_blas_thread_unless_the_environment_says(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Two workers on two cores must not each start a BLAS thread per core; a count the caller's
    environment sets is kept (monkeypatch restores what the nanny writes into this process's environment)."""
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("MKL_NUM_THREADS", "3")
    with dask_runs.connect(ClusterConfig(local_workers=1)) as client:
        (workers,) = client.run(_blas_threads).values()
    assert workers == {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "3"}


def test_a_cluster_without_workers_is_said_once_per_outage() -> None:
    """An outside walkthrough: with every worker of an external cluster killed, the bar ticked for minutes
    without a word."""
    from palpate.evaluation.dask_runs import NO_WORKER_NOTE_S, WorkerWatch

    watch = WorkerWatch("tcp://127.0.0.1:8786")
    assert watch.note(2, 0.0) == ""
    assert watch.note(0, 1.0) == ""  # the outage starts
    assert watch.note(0, 1.0 + NO_WORKER_NOTE_S - 0.1) == ""
    said = watch.note(0, 1.0 + NO_WORKER_NOTE_S)
    assert said.startswith("no Dask worker on the cluster for 10 s") and "dask worker tcp://127.0.0.1:8786" in said
    assert watch.note(0, 100.0) == ""  # once
    assert watch.note(1, 101.0) == "a Dask worker is back (1 now); the runs go on"
    assert watch.note(1, 102.0) == ""
    assert watch.note(0, 103.0) == "" and watch.note(0, 103.0 + NO_WORKER_NOTE_S).startswith("no Dask worker")


@pytest.mark.parametrize("other_thread", [False, True])
def test_a_run_interrupted_while_it_is_written_is_written_and_counted(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, other_thread: bool
) -> None:
    """A SIGINT between writing a run and counting it made the note say 'no run of it finished' of a file
    that held one (the Ctrl-C test's flake under load); with another thread alive (the Dask client's) a
    blocked signal mask held nothing back: that thread took the signal and Python raised it at once."""
    import os
    import signal
    import threading

    from palpate.evaluation import dask_runs

    stop = threading.Event()
    waiter = threading.Thread(target=stop.wait)
    if other_thread:
        waiter.start()
    log = dask_runs.RunLog(tmp_path / "runs.jsonl", resume=False)
    real_fsync = os.fsync

    def fsync_then_ctrl_c(fd: int) -> None:
        real_fsync(fd)
        os.kill(os.getpid(), signal.SIGINT)  # lands while the row is written
        for _ in range(100):  # give the Python-level handler its chance to run here
            sum(range(100))

    monkeypatch.setattr(dask_runs.os, "fsync", fsync_then_ctrl_c)
    try:
        with pytest.raises(KeyboardInterrupt):
            log.append("run-1", {"coverage": 0.5})
    finally:
        stop.set()
        if other_thread:
            waiter.join()
    log.close()
    assert "run-1" in log.rows and '"run_key": "run-1"' in (tmp_path / "runs.jsonl").read_text()
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_a_second_evaluation_into_the_same_folder_is_refused_while_the_first_writes(tmp_path: Path) -> None:
    """An outside walkthrough: two clients resuming one --out wrote every run twice, and --from-runs then
    refused the file as holding 'runs of other settings'."""
    import os

    first = RunLog(tmp_path / "runs.jsonl", resume=True)
    with pytest.raises(ConfigError, match=rf"runs\.jsonl is being written by another evaluation \(pid {os.getpid()}"):
        RunLog(tmp_path / "runs.jsonl", resume=True)
    first.append("a", {"coverage": 0.5})
    first.close()
    with RunLog(tmp_path / "runs.jsonl", resume=True) as again:
        assert list(again.rows) == ["a"]
    # a refused --resume (a broken line) lets the lock go
    (tmp_path / "runs.jsonl").write_text('{"run_key": "a"}\nnot json\n{"run_key": "b"}\n')
    with pytest.raises(ConfigError):
        RunLog(tmp_path / "runs.jsonl", resume=True)
    RunLog(tmp_path / "runs.jsonl", resume=False).close()


def test_resume_keeps_one_of_a_runs_repeated_lines(tmp_path: Path) -> None:
    path = tmp_path / "runs.jsonl"
    line = json.dumps({"run_key": "a", "coverage": 0.5})
    path.write_text(f"{line}\n{json.dumps({'run_key': 'b', 'coverage': 0.7})}\n{line}\n")  # two files cat together
    with RunLog(path, resume=True) as log:
        assert list(log.rows) == ["a", "b"]
    assert path.read_text().splitlines() == [line, json.dumps({"run_key": "b", "coverage": 0.7})]


def test_a_scheduler_lost_mid_run_says_what_is_kept_and_how_to_go_on(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An outside walkthrough: a scheduler killed mid-evaluation ended the client with a 60-line traceback
    of CommClosedError and nothing of the finished runs or --resume."""
    import contextlib

    from distributed.comm.core import CommClosedError

    class Gone:
        def scheduler_info(self) -> dict[str, object]:
            return {"workers": {"w": {}}}

        def submit(self, *args: object, **kwargs: object) -> None:
            raise CommClosedError("ConnectionPool closing.")

    @contextlib.contextmanager
    def connect(config: ClusterConfig):  # type: ignore[no-untyped-def]
        yield Gone()

    monkeypatch.setattr(dask_runs, "connect", connect)
    with RunLog(tmp_path / "runs.jsonl", resume=True) as log:
        log.append("done", {"coverage": 0.5})
        tasks = [RunTask(key="done", function=dict), RunTask(key="next", function=dict)]
        with pytest.raises(ClusterError) as lost:
            dask_runs.run_tasks(tasks, log, ClusterConfig(scheduler="tcp://head:8786", progress=False))
    assert str(lost.value) == (
        "lost the Dask scheduler tcp://head:8786 (CommClosedError: ConnectionPool closing.); 1 of its 2 run(s) are "
        f"finished in {tmp_path / 'runs.jsonl'}; the same command with --resume goes on from them (start the cluster "
        "again first)"
    )


def test_a_worker_with_other_code_or_without_a_cache_directory_is_named_not_its_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An outside walkthrough: a worker on another commit gave other results under the same run keys without
    a word, and one that could not run palpate failed most runs as their own errors, naming no worker."""
    import os

    assert dask_runs.run_checked(dask_runs.code_digest(), dict, [("a", 1)]) == {"a": 1}
    with pytest.raises(
        dask_runs.WorkerUnfitError, match=rf"^the Dask worker pid {os.getpid()} runs other palpate code"
    ):
        dask_runs.run_checked("0" * 64, dict)
    blocked = tmp_path / "a-file"
    blocked.write_text("")
    monkeypatch.setenv("PALPATE_CACHE_DIR", str(blocked / "cache"))
    dask_runs._unfit_because.cache_clear()
    try:
        with pytest.raises(dask_runs.WorkerUnfitError, match=r"cannot make its cache directory \(NotADirectoryError"):
            dask_runs.run_checked(dask_runs.code_digest(), dict)
    finally:
        dask_runs._unfit_because.cache_clear()


@pytest.mark.parametrize("answer", [MemoryError("Unable to allocate 3.07 EiB"), ValueError("bad frame")])
def test_an_address_where_no_dask_scheduler_answers_is_named(
    monkeypatch: pytest.MonkeyPatch, answer: Exception
) -> None:
    """An outside walkthrough: another protocol's bytes at --scheduler (a dashboard's port) ended in a
    traceback of numpy's MemoryError (its first bytes read as a frame length)."""
    import distributed

    def foreign(*args: object, **kwargs: object) -> None:
        raise answer

    monkeypatch.setattr(distributed, "Client", foreign)
    monkeypatch.setattr(dask_runs, "check_scheduler", lambda address, timeout_s: None)
    refused = pytest.raises(ClusterError, match=r"^what answers at tcp://head:8787 is no Dask scheduler")
    with refused, dask_runs.connect(ClusterConfig(scheduler="tcp://head:8787")):
        pass


def test_a_port_that_takes_the_connection_and_never_answers_is_named_within_the_timeout() -> None:
    """An outside walkthrough: at a port where an HTTP server listens, Dask's Client() waited for ever
    (then 40 s more in its __del__ at exit)."""
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()  # the kernel completes the connection; nothing ever answers
        address = f"tcp://127.0.0.1:{server.getsockname()[1]}"
        silent = pytest.raises(ClusterError, match=rf"^what answers at {address} is no Dask scheduler \(no answer")
        with silent, dask_runs.connect(ClusterConfig(scheduler=address, connect_timeout_s=0.5)):
            pass


class _Comm:
    """A Dask comm that answers the identity call with ``reply`` (or raises it)."""

    def __init__(self, reply: object) -> None:
        self.reply = reply
        self.aborted = False

    async def write(self, message: object) -> None:
        assert message == {"op": "identity", "reply": True}

    async def read(self) -> object:
        if isinstance(self.reply, Exception):
            raise self.reply
        return self.reply

    def abort(self) -> None:
        self.aborted = True


@pytest.mark.parametrize(
    ("reply", "said"),
    [
        ({"type": "Worker", "id": "Worker-1"}, "is a Dask worker, not the scheduler"),
        ({"type": "Nanny"}, "is a Dask nanny, not the scheduler"),
        ({"type": "Scheduler"}, None),
        ([1, 2], r"is no Dask scheduler \(its identity: \[1, 2\]\)"),
        (MemoryError("Unable to allocate 3.07 EiB"), r"is no Dask scheduler \(MemoryError: Unable"),
    ],
)
def test_the_scheduler_check_names_what_answers(
    monkeypatch: pytest.MonkeyPatch, reply: object, said: str | None
) -> None:
    import distributed.comm

    comm = _Comm(reply)

    async def opened(address: str, timeout: float, **kwargs: object) -> _Comm:
        return comm

    monkeypatch.setattr(distributed.comm, "connect", opened)
    if said is None:
        dask_runs.check_scheduler("tcp://head:8786", 1.0)

        async def in_a_notebook() -> None:  # an event loop already runs in this thread
            dask_runs.check_scheduler("tcp://head:8786", 1.0)

        asyncio.run(in_a_notebook())
    else:
        with pytest.raises(ClusterError, match=rf"^what answers at tcp://head:8786 {said}.*'Scheduler at'"):
            dask_runs.check_scheduler("tcp://head:8786", 1.0)
    assert comm.aborted


@pytest.mark.parametrize(
    "refusal",
    [
        TypeError(
            "TLS expects a `ssl_context` argument of type ssl.SSLContext (perhaps check your TLS configuration?)"
        ),
        RuntimeError("encryption required by Dask configuration, refusing communication from/to 'tcp://head:8786'"),
    ],
)
def test_security_settings_that_do_not_fit_the_address_are_named_as_such(
    monkeypatch: pytest.MonkeyPatch, refusal: Exception
) -> None:
    """The review: a tls:// scheduler without the client's TLS settings was called "no Dask scheduler", and
    require-encryption with a tcp:// address ended in a traceback."""
    import distributed.comm

    async def refused(address: str, timeout: float, **kwargs: object) -> None:
        raise refusal

    monkeypatch.setattr(distributed.comm, "connect", refused)
    with pytest.raises(
        ClusterError, match=r"^cannot connect to the Dask scheduler at tcp://head:8786: Dask's security"
    ):
        dask_runs.check_scheduler("tcp://head:8786", 1.0)


def test_a_full_disk_under_the_runs_file_is_named_and_keeps_the_runs_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An outside walkthrough: --out on a full disk ended in an ENOSPC traceback, at the lock file or at a
    run's line."""
    import errno

    from palpate import locks

    def full(*args: object, **kwargs: object) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    log = RunLog(tmp_path / "runs.jsonl", resume=True)
    log.append("first", {"x": 1})
    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(ClusterError, match=r"runs\.jsonl \(No space left on device\): its 1 run\(s\) written before"):
        log.append("second", {"x": 2})
    log.close()
    monkeypatch.setattr(locks, "hold", full)
    with pytest.raises(ConfigError, match=r"cannot write .*runs\.jsonl\.lock \(No space left on device\); give --out"):
        RunLog(tmp_path / "runs.jsonl", resume=True)


def test_a_scheduler_check_that_timed_out_before_connecting_says_no_connection(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The final read: the timeout's message is empty, and "({exc or ...})" printed "()" since an exception
    is always true."""
    import distributed.comm

    async def never(address: str, timeout: float, **kwargs: object) -> None:
        await asyncio.sleep(10)

    monkeypatch.setattr(distributed.comm, "connect", never)
    monkeypatch.setattr(dask_runs, "_listening", lambda address: False)
    with pytest.raises(ClusterError, match=r"within 0\.1 s \(no connection\); start one"):
        dask_runs.check_scheduler("tcp://head:8786", 0.1)


@pytest.mark.parametrize("advice", [None, ""])
def test_rows_of_other_settings_get_advice_only_where_the_command_has_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], advice: str | None
) -> None:
    """An outside walkthrough: eval slam, sweep slam and rescore have no --from-runs, and a sweep's file holds
    every setting's rows by design, yet each was told to give each setting an --out of its own."""
    with RunLog(tmp_path / "runs.jsonl", resume=True) as log:
        log.append("mine", {"x": 1})
        log.append("other", {"x": 2})
        options = {} if advice is None else {"foreign_rows": advice}
        dask_runs.run_tasks([RunTask(key="mine", function=dict)], log, ClusterConfig(progress=False), **options)
    note = capsys.readouterr().err.strip()
    assert note.startswith("note: 1 run in ") and ("--from-runs" in note) == (advice is None)


def _slow_row(x: int) -> dict[str, int]:
    import time

    time.sleep(0.05)
    return {"x": x}


def test_the_runs_of_a_worker_that_cannot_run_them_go_to_the_others(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """An outside walkthrough: a worker without mujoco took 11 of 12 runs and failed them in milliseconds;
    Dask's retries may land on it again. The client gives such a worker's runs to the others."""
    import contextlib

    from distributed import Client, LocalCluster, get_worker

    bad: list[str] = []

    @contextlib.contextmanager
    def connect(config: ClusterConfig):  # type: ignore[no-untyped-def]
        with (
            LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=":0") as cluster,
            Client(cluster, set_as_default=False) as client,
        ):
            bad.append(sorted(client.scheduler_info()["workers"])[0])
            yield client

    monkeypatch.setattr(dask_runs, "connect", connect)
    monkeypatch.setattr(
        dask_runs, "_unfit_because", lambda: "cannot import mujoco" if get_worker().address == bad[0] else ""
    )
    tasks = [RunTask(key=f"run-{i}", function=_slow_row, args=(i,)) for i in range(8)]  # both workers get some
    with RunLog(tmp_path / "runs.jsonl", resume=False) as log:
        outcome = dask_runs.run_tasks(tasks, log, ClusterConfig(progress=False, poll_s=0.01))
    assert outcome.ordered(tasks) == [{"x": i} for i in range(8)] and not outcome.failed
    err = capsys.readouterr().err
    assert err.count(f"the Dask worker {bad[0]} cannot import mujoco; its runs go to the other workers") == 1


def test_the_summary_names_the_runs_file_and_leaves_out_a_cluster_it_did_not_start() -> None:
    """An outside walkthrough: `eval rescore` said 'from runs.jsonl' of its rescored.jsonl, and a command
    whose runs all came from the file said '0 Dask worker(s), 0 runs/hour/worker'."""
    resumed = dask_runs.Outcome(rows={"a": {}}, resumed=1, log_name="rescored.jsonl")
    assert resumed.summary() == "1 runs done (1 from rescored.jsonl), 0 failed, 0 retried"
    ran = dask_runs.Outcome(rows={"a": {}, "b": {}}, resumed=1, workers=2, wall_s=1800.0)
    assert ran.summary() == "2 runs done (1 from runs.jsonl), 0 failed, 0 retried, 2 Dask worker(s), 1 runs/hour/worker"
