"""The thin adapter from `rerun_log.Logger` calls to a rerun recording (rerun-sdk 0.41 API).

`open_recording(save=FILE)` streams into an .rrd file (`RecordingStream.save`); `open_recording()`
spawns a viewer window (`rerun.spawn`) and streams to it. The recording has one timeline, `sim_time`
(a duration: the messages' `stamp_ns`); rerun's wall-clock `log_time` and `log_tick` are switched
off so that a log viewed twice gives the same data.
"""

from __future__ import annotations

import os
import shutil
import sys
import uuid
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from palpate.errors import ViewerError
from palpate.viewer import require_rerun
from palpate.viewer.rerun_log import KINDS, TIMELINE

APPLICATION_ID = "palpate"
#: How long closing waits for a spawned viewer to take the data still queued.
VIEWER_FLUSH_TIMEOUT_S = 10.0


class RerunLogger:
    """A `rerun_log.Logger` that logs into a rerun RecordingStream."""

    def __init__(self, recording: Any, rr: ModuleType, *, flush_timeout_s: float = 1e9, save: Path | None = None):
        """`save`: the file the recording streams into (None: a spawned viewer)."""
        self.recording = recording
        self.rr = rr
        self.flush_timeout_s = flush_timeout_s
        self.save = save
        self.calls = 0
        self._time_ns: int | None = None  # time of the next timed log call
        self._time_set_ns: int | None = None  # time the recording's cursor is at

    def set_time_ns(self, stamp_ns: int) -> None:
        # applied lazily: most messages (poses within a trail step) log nothing, and rerun's set_time costs ~25 us
        self._time_ns = int(stamp_ns)

    def log(self, path: str, kind: str, *, static: bool = False, **arrays: Any) -> None:
        if kind not in KINDS:
            raise ViewerError(f"unknown archetype {kind!r}; the viewer logs {', '.join(KINDS)}")
        archetype = getattr(self.rr, kind)(**arrays)
        if not static and self._time_ns is not None and self._time_ns != self._time_set_ns:
            self.recording.set_time(TIMELINE, duration=np.timedelta64(self._time_ns, "ns"))
            self._time_set_ns = self._time_ns
        # strict: a malformed batch raises here instead of becoming a warning in the viewer
        self.recording.log(path, archetype, static=static, strict=True)
        self.calls += 1

    def close(self) -> None:
        """Flush everything logged and close the file or viewer connection.

        Raises ViewerError when the file cannot be written or a viewer does not take the data within
        `flush_timeout_s`.
        """
        try:
            self.recording.flush(timeout_sec=self.flush_timeout_s)
        except RuntimeError as exc:  # rerun-sdk 0.41 raises RuntimeError("Flush timed out ...")
            if self.save is not None:  # its file-writer thread stopped: a full disk, a file size limit
                raise ViewerError(f"cannot write the recording {str(self.save)!r}: {exc}") from exc
            raise ViewerError(
                f"the rerun viewer did not take the data within {self.flush_timeout_s:.0f} s ({exc}); "
                "if no window opened, write a file with --save FILE.rrd"
            ) from exc
        finally:
            self.recording.disconnect()


def rerun_executable() -> str | None:
    """The `rerun` viewer binary: on PATH, else beside the running Python (an unactivated venv)."""
    found = shutil.which("rerun")
    if found:
        return found
    beside = Path(sys.executable).parent / "rerun"
    return str(beside) if beside.is_file() and os.access(beside, os.X_OK) else None


@dataclass(frozen=True)
class SaveTarget:
    """Where ``--save`` puts a recording: streamed into a hidden file beside a regular file and renamed onto
    it when whole (a failure leaves no half recording under its name), or into the path itself when it is
    a device or a pipe (/dev/null). A link is written through, to the file it names."""

    path: Path
    writing: Path

    @classmethod
    def of(cls, save: Path, *, force: bool) -> SaveTarget:
        """The target of ``--save save``; ViewerError for a folder, a missing folder, or a file without force."""
        target = save.resolve() if save.is_symlink() else save
        if target.is_dir():
            raise ViewerError(f"--save {save} is a folder; give a file name, such as {save / 'run.rrd'}")
        if target.exists() and not target.is_file():  # a device or a pipe: nothing to replace
            return cls(target, target)
        if target.exists() and not force:
            raise ViewerError(f"{save} exists; pass --force to replace it, or choose another --save file")
        if not target.parent.is_dir():
            raise ViewerError(f"cannot write the recording {str(save)!r}: its folder {target.parent} does not exist")
        return cls(target, target.with_name(f".{target.name}.partial"))

    def commit(self) -> None:
        """The whole recording under its name (ViewerError, the recording kept where it is, if it cannot be)."""
        if self.writing == self.path:
            return
        try:
            os.replace(self.writing, self.path)
        except OSError as exc:
            raise ViewerError(
                f"cannot put the recording at {self.path} ({exc.strerror or exc}); it is in {self.writing}"
            ) from exc

    def abandon(self, *, keep: bool) -> Path | None:
        """After a failure: with keep, what was recorded goes under the name (or stays where it is, if it
        cannot), which it returns; else it is deleted. None when nothing is kept."""
        if self.writing == self.path or not self.writing.exists():
            return None
        if not keep:
            self.writing.unlink(missing_ok=True)
            return None
        try:
            os.replace(self.writing, self.path)
        except OSError:
            return self.writing
        return self.path


def open_recording(*, save: Path | None = None) -> RerunLogger:
    """A logger streaming into `save` (an .rrd file) or, without `save`, into a spawned viewer."""
    rr = require_rerun()
    recording = rr.RecordingStream(APPLICATION_ID, recording_id=uuid.uuid4())
    recording.set_log_time_enabled(False)
    recording.set_log_tick_enabled(False)
    if save is not None:
        try:
            recording.save(save)
        except (OSError, ValueError, RuntimeError) as exc:
            raise ViewerError(f"cannot write the recording {str(save)!r}: {exc}") from exc
    else:
        executable = rerun_executable()
        if executable is None:
            raise ViewerError(
                "the rerun viewer binary was not found (it comes with rerun-sdk); "
                "reinstall the extra (pip install 'palpate[viewer]') or write a file with --save FILE.rrd"
            )
        try:
            rr.spawn(executable_path=executable, recording=recording)
        except (OSError, RuntimeError) as exc:
            raise ViewerError(f"cannot start the rerun viewer ({exc}); write a file with --save FILE.rrd") from exc
    recording.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)  # MuJoCo's world is z-up
    return RerunLogger(recording, rr, flush_timeout_s=1e9 if save is not None else VIEWER_FLUSH_TIMEOUT_S, save=save)
