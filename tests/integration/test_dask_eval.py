"""`palpate eval explore` on Dask: a cluster of separate processes that loses a worker midway, and an
evaluation killed midway and resumed, both give the runs and figures of an uninterrupted local run.

The evaluation is `--quick` on two small meshes written here (balls of 12 and 9 mm radius, 2 objects
x 1 run x 2 strategies = 4 runs, each reaching 80 % coverage in 12-20 contacts) with a 30-contact
budget, so that every command takes seconds.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from palpate.paths import REPO_ROOT
from tests.integration.launch_helpers import kill_session

if TYPE_CHECKING:
    from distributed import Client

pytestmark = pytest.mark.slow

#: Run fields that measure time, not what the run did.
TIMING = {"setup_s", "wall_s", "cpu_s", "plan_ms"}
COMMAND_TIMEOUT_S = 150.0


def env(cache: Path) -> dict[str, str]:
    return dict(
        os.environ,
        PALPATE_CACHE_DIR=str(cache),
        PALPATE_SCHEDULER="",
        OMP_NUM_THREADS="1",
        OPENBLAS_NUM_THREADS="1",
        MKL_NUM_THREADS="1",
        PYTHONUNBUFFERED="1",
    )


@pytest.fixture(scope="module")
def objects(tmp_path_factory: pytest.TempPathFactory) -> Path:
    import trimesh

    folder = tmp_path_factory.mktemp("objects")
    trimesh.creation.icosphere(subdivisions=2, radius=0.012).export(folder / "ball.stl")
    trimesh.creation.icosphere(subdivisions=2, radius=0.009).export(folder / "small_ball.stl")
    return folder


def eval_command(objects: Path, out: Path, *extra: str) -> list[str]:
    return [
        sys.executable,
        "-m",
        "palpate.cli",
        "eval",
        "explore",
        "--quick",
        "--strategies",
        "igef,gpv",
        "--objects",
        str(objects),
        "--max-contacts",
        "30",
        "--json",
        "--out",
        str(out),
        *extra,
    ]


def run_eval(objects: Path, out: Path, cache: Path, *extra: str) -> tuple[dict[str, object], str]:
    """Run the evaluation to the end: its --json summary and its stderr."""
    done = subprocess.run(
        eval_command(objects, out, *extra),
        cwd=REPO_ROOT,
        env=env(cache),
        capture_output=True,
        text=True,
        timeout=COMMAND_TIMEOUT_S,
        check=False,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1]), done.stderr


def runs(out: Path) -> dict[str, dict[str, object]]:
    """runs.jsonl by run key, timing fields left out; fails if a key appears twice."""
    rows = [json.loads(line) for line in (out / "runs.jsonl").read_text().splitlines() if line.strip()]
    keys = [r["run_key"] for r in rows]
    assert len(keys) == len(set(keys)), f"a run was written twice: {keys}"
    return {r["run_key"]: {k: v for k, v in r.items() if k not in TIMING} for r in rows}


def wait_for_lines(path: Path, n: int, proc: subprocess.Popen[bytes], timeout_s: float = COMMAND_TIMEOUT_S) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if path.exists() and len(path.read_text().splitlines()) >= n:
            return
        assert proc.poll() is None, f"the evaluation ended (exit {proc.returncode}) before {n} run(s) finished"
        time.sleep(0.2)
    raise AssertionError(f"fewer than {n} run(s) in {path} after {timeout_s:g} s")


@pytest.fixture(scope="module")
def reference(objects: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[dict[str, object], Path]:
    """The uninterrupted run on the default local cluster."""
    out = tmp_path_factory.mktemp("reference")
    summary, _ = run_eval(objects, out, tmp_path_factory.mktemp("cache"))
    return summary, out


def spawn(args: list[str], log: Path, cache: Path) -> subprocess.Popen[bytes]:
    with log.open("wb") as f:
        return subprocess.Popen(
            args, cwd=REPO_ROOT, env=env(cache), stdout=f, stderr=subprocess.STDOUT, start_new_session=True
        )


@pytest.fixture
def cluster(tmp_path: Path) -> Iterator[tuple[str, list[subprocess.Popen[bytes]], list[Path]]]:
    """A Dask scheduler and two workers, each its own process (workers without a nanny, so that killing
    one kills the worker) with its own cache folder: address, worker processes, worker caches."""
    scheduler_file = tmp_path / "scheduler.json"
    procs = [
        spawn(
            [
                sys.executable,
                "-m",
                "distributed.cli.dask_scheduler",
                "--host",
                "127.0.0.1",
                "--port",
                "0",
                "--no-dashboard",
                "--scheduler-file",
                str(scheduler_file),
            ],
            tmp_path / "scheduler.log",
            tmp_path / "scheduler-cache",
        )
    ]
    workers, caches = [], []
    try:
        deadline = time.monotonic() + 60
        while not scheduler_file.exists() or not scheduler_file.read_text().strip():
            assert procs[0].poll() is None, (tmp_path / "scheduler.log").read_text()
            assert time.monotonic() < deadline, "the scheduler wrote no scheduler file in 60 s"
            time.sleep(0.1)
        address = json.loads(scheduler_file.read_text())["address"]
        for i in range(2):
            caches.append(tmp_path / f"worker{i}-cache")
            workers.append(
                spawn(
                    [
                        sys.executable,
                        "-m",
                        "distributed.cli.dask_worker",
                        address,
                        "--nthreads",
                        "1",
                        "--no-nanny",
                        "--host",
                        "127.0.0.1",
                        "--no-dashboard",
                        "--name",
                        f"worker{i}",
                    ],
                    tmp_path / f"worker{i}.log",
                    caches[-1],
                )
            )
        procs += workers
        yield address, workers, caches
    finally:
        for proc in reversed(procs):
            kill_session(proc)


def runs_held(observer: Client) -> dict[str, set[str]]:
    """Worker name -> the runs the scheduler has given it (runs queued on the scheduler, waiting for a
    free worker, are in no worker's list)."""
    names = {a: str(w["name"]) for a, w in observer.scheduler_info()["workers"].items()}
    held = observer.processing()
    return {names[a]: {str(k) for k in keys if str(k).startswith("explore-")} for a, keys in held.items() if a in names}


def stop_a_worker_midway(
    observer: Client, workers: list[subprocess.Popen[bytes]], proc: subprocess.Popen[bytes], timeout_s: float = 120.0
) -> int:
    """The index of a worker, stopped (SIGSTOP), that has finished a run and holds another.

    Watched from the start: a run that leaves a worker's list is done (or was moved to the other).
    A worker seen with a run may finish it before a kill lands; stopped, it cannot, and after a
    moment for any result already on its way the scheduler's list is checked again (if the run got
    away, the worker is continued).
    """
    done: dict[str, set[str]] = {}
    seen: dict[str, set[str]] = {}
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        assert proc.poll() is None, f"the evaluation ended (exit {proc.returncode}) before a worker was seen midway"
        for name, runs in runs_held(observer).items():
            done.setdefault(name, set()).update(seen.get(name, set()) - runs)
            seen[name] = runs
            if done[name] and runs:
                index = int(name.removeprefix("worker"))
                os.kill(workers[index].pid, signal.SIGSTOP)
                time.sleep(2.0)  # a result already sent reaches the scheduler meanwhile, even a loaded one
                if runs_held(observer).get(name):
                    return index
                os.kill(workers[index].pid, signal.SIGCONT)
        time.sleep(0.02)
    raise AssertionError(f"no worker was seen with a run after finishing one in {timeout_s:g} s")


def test_a_cluster_that_loses_a_worker_runs_every_run_once_with_the_local_results(
    objects: Path,
    reference: tuple[dict[str, object], Path],
    cluster: tuple[str, list[subprocess.Popen[bytes]], list[Path]],
    tmp_path: Path,
) -> None:
    from distributed import Client

    address, workers, caches = cluster
    out = tmp_path / "out"
    with Client(address, timeout=30, set_as_default=False) as observer:
        observer.wait_for_workers(2, timeout=60)
        proc = spawn(eval_command(objects, out, "--scheduler", address), tmp_path / "eval.log", tmp_path / "eval-cache")
        try:
            # in the middle: kill a worker that has finished a run and holds another
            kill_session(workers[stop_a_worker_midway(observer, workers, proc)])
            proc.wait(timeout=COMMAND_TIMEOUT_S)
        finally:
            kill_session(proc)
    log = (tmp_path / "eval.log").read_text()
    failures = "\n".join(line for line in log.splitlines() if line.startswith("run failed"))
    assert proc.returncode == 0, failures + "\n" + log[-2000:]
    summary = json.loads(log.strip().splitlines()[-1])
    expected_summary, expected_out = reference
    assert runs(out) == runs(expected_out)
    assert summary == expected_summary
    assert summary["igef"]["runs_completed"] == summary["gpv"]["runs_completed"] == 2  # type: ignore[index]
    counts = re.search(r"(\d+) failed, (\d+) retried", log)
    assert counts, log[-3000:]
    assert int(counts[1]) == 0
    assert int(counts[2]) >= 1, "the runs of the killed worker were not counted as retried"
    # no shared filesystem: each worker ran from its own copy of the meshes, named by content
    assert any(list((cache / "files").glob("*.stl")) for cache in caches)


def test_a_killed_evaluation_resumes_to_the_tables_of_an_uninterrupted_run(
    objects: Path, reference: tuple[dict[str, object], Path], tmp_path: Path
) -> None:
    out = tmp_path / "out"
    cache = tmp_path / "cache"
    proc = spawn(eval_command(objects, out, "--workers", "1"), tmp_path / "killed.log", cache)
    try:
        wait_for_lines(out / "runs.jsonl", 1, proc)
    finally:
        kill_session(proc)  # the whole session: the command and its local cluster
    if len(runs(out)) == 4:
        # every run ended before the kill landed (the command may write several finished runs at
        # once): resume from the first run alone, as if the kill had come right after it
        first = (out / "runs.jsonl").read_text().splitlines()[0]
        (out / "runs.jsonl").write_text(first + "\n")
    finished = runs(out)
    assert 1 <= len(finished) < 4
    summary, stderr = run_eval(objects, out, cache, "--resume")
    expected_summary, expected_out = reference
    assert f"({len(finished)} from runs.jsonl)" in (out / "tables.md").read_text()
    assert f"{4 - len(finished)} run(s) on local Dask cluster" in stderr
    assert runs(out) == runs(expected_out)
    assert summary == expected_summary
    tables = (out / "tables.md").read_text().split("## Averages", 1)[1]
    assert tables == (expected_out / "tables.md").read_text().split("## Averages", 1)[1]


def test_a_terminated_evaluation_says_how_to_go_on_as_ctrl_c_does(objects: Path, tmp_path: Path) -> None:
    """SIGTERM (a batch scheduler's, `timeout`'s) ended the command without a word; the runs were kept."""
    out = tmp_path / "out"
    proc = spawn(eval_command(objects, out, "--workers", "1"), tmp_path / "terminated.log", tmp_path / "cache")
    try:
        wait_for_lines(out / "runs.jsonl", 1, proc)
        proc.send_signal(signal.SIGTERM)  # the command only, as a scheduler would
        code = proc.wait(timeout=60)
    finally:
        kill_session(proc)
    log = (tmp_path / "terminated.log").read_text()
    if "interrupted" not in log and code in (0, -signal.SIGTERM):  # after the runs: done, or killed outright
        pytest.skip("every run ended before the signal landed")
    assert code == 130, log
    assert re.search(rf"\d of its 4 run\(s\) are finished in {re.escape(str(out / 'runs.jsonl'))}; the same", log), log
