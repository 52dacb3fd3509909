"""`palpate view`: optional rerun, clear errors, and an .rrd written from a small MCAP log."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from palpate import cli
from palpate.viewer import EXTRA_HINT
from tests.unit.viewer.viewer_messages import session, surface, write_mcap


@pytest.fixture
def log_file(tmp_path: Path) -> Path:
    path = tmp_path / "run.mcap"
    write_mcap(path, session())
    return path


def test_every_command_registers_without_rerun() -> None:
    # a fresh interpreter where any `import rerun` raises ImportError, as in an install without the extra
    code = (
        "import sys; sys.modules['rerun'] = None\n"
        "from palpate import cli\n"
        "parser = cli.build_parser()\n"
        "args = parser.parse_args(['view', '--log', 'x.mcap', '--save', 'x.rrd', '--topics', 'a', 'b'])\n"
        "assert args.func.__module__ == 'palpate.commands.view' and args.topics == ['a', 'b']\n"
        "assert 'rerun' not in {m.split('.')[0] for m, v in sys.modules.items() if v is not None}\n"
        "print(sorted(parser._subparsers._group_actions[0].choices))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    assert "'view'" in done.stdout and "'launch'" in done.stdout


def test_view_without_rerun_names_the_extra(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], log_file: Path, tmp_path: Path
) -> None:
    monkeypatch.setitem(sys.modules, "rerun", None)
    out = tmp_path / "out.rrd"
    assert cli.main(["view", "--log", str(log_file), "--save", str(out)]) == 2
    assert capsys.readouterr().err == f"palpate view: {EXTRA_HINT}\n"  # one prefix, not two
    assert EXTRA_HINT == "the viewer extra is not installed: pip install 'palpate[viewer]'"
    assert not out.exists()


def test_view_without_display_suggests_save(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], log_file: Path
) -> None:
    pytest.importorskip("rerun")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    assert cli.main(["view", "--log", str(log_file)]) == 2
    assert "--save FILE.rrd" in capsys.readouterr().err


def test_view_missing_log_and_conflicting_sources(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    pytest.importorskip("rerun")
    out = tmp_path / "out.rrd"
    assert cli.main(["view", "--log", str(tmp_path / "none.mcap"), "--save", str(out)]) == 2
    assert "no log file" in capsys.readouterr().err
    assert not out.exists()
    assert cli.main(["view", "--log", "a.mcap", "--bus", str(tmp_path), "--save", str(out)]) == 2
    assert "not both" in capsys.readouterr().err


def test_view_damaged_log_says_recover(capsys: pytest.CaptureFixture[str], log_file: Path, tmp_path: Path) -> None:
    pytest.importorskip("rerun")
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(log_file.read_bytes()[: log_file.stat().st_size // 2])
    assert cli.main(["view", "--log", str(damaged), "--save", str(tmp_path / "out.rrd")]) == 2
    err = capsys.readouterr().err
    assert "damaged.mcap ends before the log's footer" in err and "palpate bag recover" in err  # as bag says
    assert err.rstrip().endswith("and view the result")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["damaged.mcap", "run.mcap"]  # no half recording
    damaged.write_bytes(b"not a log")
    assert cli.main(["view", "--log", str(damaged), "--save", str(tmp_path / "out.rrd")]) == 2
    assert capsys.readouterr().err.rstrip().endswith("(it does not start with MCAP's magic bytes)")


def test_save_replaces_a_file_only_with_force(
    capsys: pytest.CaptureFixture[str], log_file: Path, tmp_path: Path
) -> None:
    pytest.importorskip("rerun")
    out = tmp_path / "run.rrd"
    out.write_bytes(b"earlier")
    assert cli.main(["view", "--log", str(log_file), "--save", str(out)]) == 2
    assert "exists; pass --force" in capsys.readouterr().err
    assert out.read_bytes() == b"earlier"
    assert cli.main(["view", "--log", str(log_file), "--save", str(out), "--force"]) == 0
    assert out.stat().st_size > len(b"earlier")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.mcap", "run.rrd"]


def test_a_log_with_nothing_to_show_writes_no_recording_and_exits_1(
    capsys: pytest.CaptureFixture[str], log_file: Path, tmp_path: Path
) -> None:
    """An outside walkthrough: `--topics clock` said "nothing to show", yet exited 0 with an empty .rrd."""
    pytest.importorskip("rerun")
    out = tmp_path / "clock.rrd"
    assert cli.main(["view", "--log", str(log_file), "--save", str(out), "--topics", "clock"]) == 1
    assert "nothing to show; the viewer shows ObjectTruth" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.mcap"]  # neither the file nor a partial one


def test_save_writes_an_rrd_with_the_scene(capsys: pytest.CaptureFixture[str], log_file: Path, tmp_path: Path) -> None:
    pytest.importorskip("rerun")
    from rerun.chunk import RrdReader

    out = tmp_path / "run.rrd"
    assert cli.main(["view", "--log", str(log_file), "--save", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "14 of 16 messages shown" in printed and str(out) in printed  # the two clocks are not shown
    assert out.stat().st_size > 0
    chunks = list(RrdReader(out).stream())
    entities = {c.entity_path for c in chunks}
    for expected in (
        "/world/truth/object",
        "/world/sensors/contacts/normals",
        "/world/controller/events/contacts",
        "/world/surface/mesh/local",
        "/world/planner/target/candidates",
        "/world/controller/trajectory/curve",
        "/world/sensors/effector_pose/trail/00000",
        "/world/map/occupancy/best",
        "/metrics/controller/events/prediction_miss_mm",
    ):
        assert expected in entities
    timed = [c for c in chunks if c.entity_path.startswith("/world/surface")]
    assert timed and all(c.timeline_names == ["sim_time"] for c in timed)
    tips = [c for c in chunks if c.entity_path == "/world/sensors/effector_pose/tip"]
    stamps = [int(t.value) for c in tips for t in c.to_record_batch().column("sim_time")]
    assert stamps == [k * 1_000_000 for k in range(6)]  # the sim-time timeline holds the poses' stamp_ns
    assert all(c.is_static for c in chunks if c.entity_path == "/world/truth/object")


def test_save_targets_a_folder_a_device_and_a_link_as_a_user_expects(tmp_path: Path) -> None:
    """An outside review: `--save DIR --force` wrote the whole recording and then failed in a traceback,
    `--save /dev/null --force` made /dev/null a regular file, a link was replaced by a file."""
    pytest.importorskip("rerun")
    from palpate.errors import ViewerError
    from palpate.viewer.sink import SaveTarget

    with pytest.raises(ViewerError, match="is a folder; give a file name"):
        SaveTarget.of(tmp_path, force=True)
    with pytest.raises(ViewerError, match=r"its folder .* does not exist"):
        SaveTarget.of(tmp_path / "no" / "run.rrd", force=False)
    device = SaveTarget.of(Path("/dev/null"), force=False)  # a device is written as it is, never replaced
    assert device.writing == device.path == Path("/dev/null")
    real = tmp_path / "real.rrd"
    real.write_bytes(b"old")
    link = tmp_path / "link.rrd"
    link.symlink_to(real)
    through = SaveTarget.of(link, force=True)
    assert through.path == real.resolve() and through.writing.name == ".real.rrd.partial"
    through.writing.write_bytes(b"new")
    through.commit()
    assert link.is_symlink() and real.read_bytes() == b"new"
    # after a failure: a log's recording is deleted (view it again), a live one's kept under the name
    again = SaveTarget.of(tmp_path / "live.rrd", force=False)
    again.writing.write_bytes(b"so far")
    assert again.abandon(keep=True) == tmp_path / "live.rrd" and (tmp_path / "live.rrd").read_bytes() == b"so far"
    gone = SaveTarget.of(tmp_path / "log.rrd", force=False)
    gone.writing.write_bytes(b"half")
    assert gone.abandon(keep=False) is None and not gone.writing.exists() and not gone.path.exists()


def test_topics_filter(capsys: pytest.CaptureFixture[str], log_file: Path, tmp_path: Path) -> None:
    pytest.importorskip("rerun")
    from rerun.chunk import RrdReader

    out = tmp_path / "surface.rrd"
    assert cli.main(["view", "--log", str(log_file), "--save", str(out), "--topics", "surface/mesh"]) == 0
    assert "1 of 1 messages shown" in capsys.readouterr().out
    entities = {c.entity_path for c in RrdReader(out).stream()} - {"/__properties", "/world"}
    assert entities == {"/world/surface/mesh/local"}

    typo = tmp_path / "typo.rrd"
    assert (
        cli.main(["view", "--log", str(log_file), "--save", str(typo), "--topics", "surface/mesh", "surface/msh"]) == 0
    )
    captured = capsys.readouterr()
    assert f"{log_file} has no topic surface/msh (did you mean 'surface/mesh'?)" in captured.err  # named
    assert "1 of 1 messages shown" in captured.out


def test_the_live_viewer_ends_with_a_stopped_or_a_failed_run(tmp_path: Path) -> None:
    """The clock source closes a failed run with RunControl "fail": the viewer ended only on "stop"."""
    from palpate.messages import codec
    from palpate.messages.schemas import RunControl
    from palpate.viewer.sources import BusSource

    for command, ends in (("stop", True), ("fail", True), ("pause", False)):
        source = BusSource(tmp_path)
        try:
            source._control(codec.encode(RunControl(stamp_ns=0, command=command, reason="x")))
            assert source.stopped is ends, command
        finally:
            source.close()


def test_a_message_the_viewer_cannot_draw_is_skipped_and_counted(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """A surface that decodes but names variance at vertices it lacks: the viewer goes on without it, as
    a node skips such an input, and says so (it ended the viewer)."""
    pytest.importorskip("rerun")
    bad = surface(5_000_000)
    bad.variance_vertices[:] = [32, 33, 34, 35]
    log = tmp_path / "run.mcap"
    write_mcap(log, [*session(), ("surface/mesh", bad)])
    assert cli.main(["view", "--log", str(log), "--save", str(tmp_path / "run.rrd")]) == 0
    captured = capsys.readouterr()
    assert "14 of 17 messages shown" in captured.out
    assert "1 messages with values it cannot draw skipped, last: surface/mesh at 5000000 ns: variance_vertices:" in (
        captured.err
    )


class _StoppedStream:
    """A rerun RecordingStream whose flush fails as rerun-sdk's does when its writer thread stopped."""

    disconnected = False

    def flush(self, timeout_sec: float) -> None:
        raise RuntimeError("File-writer thread shut down prematurely")

    def disconnect(self) -> None:
        self.disconnected = True


@pytest.mark.parametrize(
    ("save", "expected"),
    [
        (Path("x.rrd"), "cannot write the recording 'x.rrd': File-writer"),
        (None, "the rerun viewer did not take the data within 10 s"),
    ],
)
def test_a_failed_flush_is_a_write_error_when_saving_and_a_timeout_with_a_viewer(
    save: Path | None, expected: str
) -> None:
    """An outside walkthrough: a full disk under --save said the viewer did not take the data within
    1000000000 s, and suggested --save."""
    from palpate.errors import ViewerError
    from palpate.viewer.sink import RerunLogger

    stream = _StoppedStream()
    logger = RerunLogger(stream, None, flush_timeout_s=10.0, save=save)  # type: ignore[arg-type]
    with pytest.raises(ViewerError, match=expected):
        logger.close()
    assert stream.disconnected
