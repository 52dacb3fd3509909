"""`palpate bag export --foxglove`: a log of every exported type, exported, read back with the mcap reader
and decoded with nothing but the schemas the file carries (protobuf descriptors, JSON Schema), as Foxglove does."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader

from palpate import cli
from palpate.geometry.rotations import quat_to_matrix
from palpate.messages.schemas import Clock, NodeStatus
from tests.unit.viewer.viewer_messages import TETRA_F, TETRA_V, contacts, grid, session, surface, write_mcap

pytest.importorskip("foxglove")
protobuf = pytest.importorskip("google.protobuf")
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory  # noqa: E402

MS = 1_000_000


def status(stamp_ns: int) -> NodeStatus:
    return NodeStatus(
        stamp_ns=stamp_ns,
        node="mapper",
        state="running",
        message="",
        counter_names=["messages_in", "decode_errors"],
        counter_values=np.array([12, 0], dtype=np.int64),
        metric_names=["n_eff", "unknown"],
        metric_values=np.array([42.5, np.nan]),
    )


@pytest.fixture
def exported(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> Path:
    log = tmp_path / "run.mcap"
    write_mcap(log, [*session(), ("status", status(10 * MS))])
    out = tmp_path / "foxglove.mcap"
    assert cli.main(["bag", "export", str(log), "-o", str(out), "--foxglove"]) == 0
    assert "exported 15 of 17 messages" in capsys.readouterr().out  # the two clocks are not exported
    return out


def read_back(path: Path) -> dict[str, list[tuple[str, str, int, Any]]]:
    """Per topic: (schema name, schema encoding, log time, decoded message) from the file's own schemas."""
    classes: dict[int, Any] = {}
    out: dict[str, list[tuple[str, str, int, Any]]] = {}
    with path.open("rb") as stream:
        reader = make_reader(stream)
        assert reader.get_header().profile == ""
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            assert schema is not None
            if schema.encoding == "protobuf":
                assert channel.message_encoding == "protobuf"
                if schema.id not in classes:
                    pool = descriptor_pool.DescriptorPool()
                    for file in descriptor_pb2.FileDescriptorSet.FromString(schema.data).file:
                        pool.Add(file)
                    classes[schema.id] = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))
                decoded = classes[schema.id].FromString(message.data)
            else:
                assert (schema.encoding, channel.message_encoding) == ("jsonschema", "json")
                assert json.loads(schema.data)["type"] == "object"
                decoded = json.loads(message.data)
            out.setdefault(channel.topic, []).append((schema.name, schema.encoding, message.log_time, decoded))
    return out


def one(rows: list[Any]) -> Any:
    assert len(rows) == 1, rows
    return rows[0]


def xyz(points: Any) -> np.ndarray:
    return np.array([[p.x, p.y, p.z] for p in points])


def test_every_kind_decodes_from_the_files_own_schemas(exported: Path) -> None:
    got = read_back(exported)
    assert {t: {(s, e) for s, e, _, _ in rows} for t, rows in got.items()} == {
        "truth/object": {("foxglove.SceneUpdate", "protobuf")},
        "surface/mesh": {("foxglove.SceneUpdate", "protobuf")},
        "sensors/contacts": {("foxglove.SceneUpdate", "protobuf")},
        "controller/events": {("foxglove.SceneUpdate", "protobuf")},
        "controller/events/metrics": {("palpate.TouchMetrics", "jsonschema")},
        "planner/target": {("foxglove.SceneUpdate", "protobuf")},
        "controller/trajectory": {("foxglove.SceneUpdate", "protobuf")},
        "sensors/effector_pose": {("foxglove.FrameTransforms", "protobuf")},
        "map/occupancy": {("foxglove.SceneUpdate", "protobuf")},
        "status": {("palpate.NodeStatus", "jsonschema")},
    }

    # the true mesh: one TriangleListPrimitive with the mesh's vertices and faces, in frame world
    _, _, stamp, update = one(got["truth/object"])
    (entity,) = update.entities
    assert (entity.id, entity.frame_id, stamp) == ("truth", "world", 0)
    (mesh,) = entity.triangles
    np.testing.assert_allclose(xyz(mesh.points), TETRA_V, atol=0)
    assert list(mesh.indices) == TETRA_F.ravel().tolist()

    # the estimated surface: per-vertex colours, entity named after the region, stamped with sim time
    _, _, stamp, update = one(got["surface/mesh"])
    (entity,) = update.entities
    assert entity.id == "local" and stamp == 7 * MS
    assert (entity.timestamp.seconds, entity.timestamp.nanos) == (0, 7 * MS)
    assert len(entity.triangles[0].colors) == len(entity.triangles[0].points) == 4

    # contacts with normals: a Foxglove arrow points along its pose's +x axis
    sent = contacts(6 * MS, 2)
    _, _, _, update = one(got["sensors/contacts"])
    (entity,) = update.entities
    assert len(entity.spheres) == len(entity.arrows) == 2
    for arrow, origin, normal in zip(entity.arrows, sent.positions_m, sent.normals, strict=True):
        q = arrow.pose.orientation
        np.testing.assert_allclose(quat_to_matrix([q.w, q.x, q.y, q.z])[:, 0], normal, atol=1e-12)
        p = arrow.pose.position
        np.testing.assert_allclose([p.x, p.y, p.z], origin, atol=0)

    # the touches so far, with the predicted -> actual segment, and their metrics as JSON for plots
    first, second = got["controller/events"]
    assert len(first[3].entities[0].spheres) == 1 and len(second[3].entities[0].spheres) == 2
    (miss,) = second[3].entities[0].lines
    np.testing.assert_allclose(xyz(miss.points), [[0.02, 0.001, 0.02], [0.02, 0, 0.02]], atol=0)
    metrics = [row[3] for row in got["controller/events/metrics"]]
    assert "prediction_miss_mm" not in metrics[0]  # the first touch had no prediction (NaN)
    assert metrics[1]["index"] == 1 and metrics[1]["travelled_m"] == pytest.approx(0.2)
    assert metrics[1]["prediction_miss_mm"] == pytest.approx(1.0, abs=1e-9)

    # the fingertip pose as a transform world -> fingertip, one per pose, at the pose's stamp
    poses = got["sensors/effector_pose"]
    assert [stamp for _, _, stamp, _ in poses] == [k * MS for k in range(6)]
    (transform,) = poses[3][3].transforms
    assert (transform.parent_frame_id, transform.child_frame_id) == ("world", "fingertip")
    t = transform.translation
    np.testing.assert_allclose([t.x, t.y, t.z], [0.006, 0, 0.05], atol=0)
    assert transform.rotation.w == 1.0

    # the occupancy grid: a cube per cell with log-odds > 0, centred in its cell
    _, _, _, update = one(got["map/occupancy"])
    (entity,) = update.entities
    g = grid(9 * MS)
    assert entity.id == "best" and len(entity.cubes) == int((g.log_odds > 0).sum()) == 3
    first_cell = entity.cubes[0]  # flat index 0: cell (0, 0, 0)
    np.testing.assert_allclose(
        [first_cell.pose.position.x, first_cell.pose.position.y, first_cell.pose.position.z],
        g.origin_m + 0.5 * g.resolution_m,
        atol=1e-15,
    )
    assert first_cell.size.x == g.resolution_m

    # the planner's target and the trajectory
    _, _, _, update = one(got["planner/target"])
    assert len(update.entities[0].spheres) == 5 + 2 and update.entities[0].texts[0].text == "igef 0.9"
    _, _, _, update = one(got["controller/trajectory"])
    assert len(update.entities[0].lines[0].points) == 64

    # a status: counters and finite metrics as numbers
    _, _, _, values = one(got["status"])
    assert values == {
        "node": "mapper",
        "state": "running",
        "message": "",
        "messages_in": 12,
        "decode_errors": 0,
        "n_eff": 42.5,
    }


def test_export_is_reproducible_and_filters_topics(exported: Path, tmp_path: Path) -> None:
    log = tmp_path / "run.mcap"
    again = tmp_path / "again.mcap"
    assert cli.main(["bag", "export", str(log), "-o", str(again), "--foxglove"]) == 0
    assert again.read_bytes() == exported.read_bytes()
    only = tmp_path / "only.mcap"
    assert cli.main(["bag", "export", str(log), "-o", str(only), "--foxglove", "--topics", "map/occupancy"]) == 0
    assert set(read_back(only)) == {"map/occupancy"}


def test_export_needs_a_format_and_the_extra(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    log = tmp_path / "run.mcap"
    write_mcap(log, session())
    with pytest.raises(SystemExit) as exc:
        cli.main(["bag", "export", str(log), "-o", str(tmp_path / "out.mcap")])
    assert exc.value.code == 2 and "--foxglove" in capsys.readouterr().err
    before = log.read_bytes()
    assert cli.main(["bag", "export", str(log), "-o", str(log), "--foxglove"]) == 2
    assert "overwrite its input" in capsys.readouterr().err and log.read_bytes() == before
    monkeypatch.setitem(sys.modules, "foxglove.messages", None)
    assert cli.main(["bag", "export", str(log), "-o", str(tmp_path / "out.mcap"), "--foxglove"]) == 2
    assert "pip install 'palpate[foxglove]'" in capsys.readouterr().err


def test_a_failed_export_leaves_no_output(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out.mcap"
    folder = tmp_path / "folder"
    folder.mkdir()
    assert cli.main(["bag", "export", str(folder), "-o", str(out), "--foxglove"]) == 2
    statuses = tmp_path / "statuses.mcap"  # nothing the export converts
    write_mcap(statuses, [("clock", Clock(stamp_ns=0, tick=0, period_ns=10_000_000, lockstep=True))])
    assert cli.main(["bag", "export", str(statuses), "-o", str(out), "--foxglove"]) == 2
    assert "nothing to export" in capsys.readouterr().err
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["folder", "statuses.mcap"]
    out.write_bytes(b"earlier export")  # an existing output stays as it was, even with --force
    assert cli.main(["bag", "export", str(statuses), "-o", str(out), "--foxglove", "--force"]) == 2
    assert out.read_bytes() == b"earlier export"


def test_a_message_the_export_cannot_draw_is_skipped_and_counted(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A surface that decodes but names variance at vertices it lacks (a damaged or foreign log): the
    export goes on without it, as a node skips such an input, and says so (it ended the export, exit 2)."""
    bad = surface(5 * MS)
    bad.variance_vertices[:] = np.arange(4, dtype=np.int32) + 32
    log = tmp_path / "run.mcap"
    write_mcap(log, [*session(), ("surface/mesh", bad)])
    out = tmp_path / "foxglove.mcap"
    assert cli.main(["bag", "export", str(log), "-o", str(out), "--foxglove"]) == 0
    printed = capsys.readouterr().out
    assert "exported 14 of 17 messages" in printed  # 16 in the session (2 clocks), 1 unusable
    assert "1 unusable skipped (last: surface/mesh at 5000000 ns: variance_vertices:" in printed
    assert len(read_back(out)["surface/mesh"]) == 1  # the good surface only
