"""`flush_before_exit`: what a node queued just before it ends reaches its subscribers."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import zmq

from palpate.runtime.node import flush_before_exit

#: A child that queues a burst for a slow reader, closes its socket and exits at once: without the
#: flush most of the burst dies with the process (about 35 of 300 arrive).
CHILD = """
import sys, zmq
from palpate.runtime.node import flush_before_exit
context = zmq.Context.instance()
push = context.socket(zmq.PUSH)
push.connect(sys.argv[1])
for i in range(int(sys.argv[2])):
    push.send(i.to_bytes(4, "little") + bytes(100_000))
push.close(linger=30_000)
sys.exit(0 if flush_before_exit(context, timeout_s=30.0) else 1)
"""


def test_a_burst_queued_before_exit_reaches_a_slow_reader(tmp_path: Path) -> None:
    context = zmq.Context()
    pull = context.socket(zmq.PULL)
    pull.setsockopt(zmq.RCVHWM, 1)  # the reader holds back one message: the rest waits in the child
    pull.setsockopt(zmq.RCVBUF, 4096)
    endpoint = f"ipc://{tmp_path / 'burst'}"
    pull.bind(endpoint)
    count = 300
    child = subprocess.Popen([sys.executable, "-c", CHILD, endpoint, str(count)])
    try:
        got = []
        while len(got) < count and pull.poll(5000 if got else 60_000):  # the child starts Python first
            got.append(int.from_bytes(pull.recv()[:4], "little"))
            time.sleep(0.002)  # a reader slower than the writer
        assert child.wait(timeout=60) == 0
        assert got == list(range(count))
    finally:
        child.kill()
        pull.close(linger=0)
        context.term()


def test_a_socket_left_open_does_not_hold_the_exit() -> None:
    context = zmq.Context()
    left_open = context.socket(zmq.PUB)
    start = time.monotonic()
    assert flush_before_exit(context, timeout_s=0.3) is False
    assert time.monotonic() - start < 2.0
    left_open.close(linger=0)  # the waiting term() then returns in its thread
