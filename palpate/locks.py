"""Exclusive claims between processes of one machine: a lock file, locked with flock, holding the pid of the
process that holds it (for the message of the one refused). The system drops a lock when its file is closed
or its process ends, however it ends; the file stays (unlinked, a newcomer could lock another inode)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import IO


class LockHeldError(Exception):
    """Another process holds the lock: ``holder`` is the pid it wrote ("?" when unreadable)."""

    def __init__(self, holder: str) -> None:
        super().__init__(holder)
        self.holder = holder


def hold(path: Path) -> IO[str]:
    """Lock the file ``path`` (made if missing) for this process and write its pid into it; the lock lasts
    while the returned file is open. LockHeldError when another process holds it; OSError when the file
    cannot be made or written (a folder of another user, a full disk)."""
    import fcntl  # POSIX only; the viewer, which imports the bus, also runs elsewhere

    handle = open(path, "a+")  # noqa: SIM115 (held by the caller)
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        handle.seek(0)
        holder = handle.read().strip() or "?"
        handle.close()
        raise LockHeldError(holder) from None
    try:
        handle.seek(0)
        handle.truncate()
        handle.write(str(os.getpid()))
        handle.flush()
    except OSError:  # a full disk: the caller names it; the lock goes with the file
        handle.close()
        raise
    return handle
