"""Objects: scene specs, generated primitives, mesh files and their bad-input errors, MJCF text."""

from __future__ import annotations

import math
import os
import warnings
from pathlib import Path

import mujoco
import numpy as np
import pytest
import trimesh

from palpate.config import load
from palpate.errors import ConfigError, MeshError, MeshWarning
from palpate.geometry.mesh_query import ExactContactSensor
from palpate.nodes.sim import objects
from palpate.nodes.sim.decomposition import convex_decomposition
from palpate.nodes.sim.objects import (
    RUBIKS_CUBE_EDGE_M,
    ObjectSpec,
    load_object,
    mujoco_hull_mesh,
    sample_surface,
    sample_surface_faces,
)


@pytest.fixture(autouse=True)
def _cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PALPATE_CACHE_DIR", str(tmp_path / "cache"))


def _mesh_spec(path: Path, scale: float = 1.0) -> ObjectSpec:
    return ObjectSpec(kind="mesh", path=str(path), scale=scale)


def _model(assets: str, geoms: str, extra: str = "") -> mujoco.MjModel:
    xml = f"<mujoco><asset>{assets}</asset><worldbody>{geoms}{extra}</worldbody></mujoco>"
    return mujoco.MjModel.from_xml_string(xml)


# --- specs -----------------------------------------------------------------------------------------
def test_load_fills_defaults_and_converts_lists() -> None:
    spec = load(ObjectSpec, {"kind": "cube", "position_m": [0.1, 0, 0.2]})
    assert spec.size_m == (0.05,)
    assert spec.position_m == (0.1, 0.0, 0.2)
    assert spec.quaternion_wxyz == (1.0, 0.0, 0.0, 0.0)
    assert load(ObjectSpec, {"kind": "sphere", "size_m": 0.03}).size_m == (0.03,)
    blank = load(ObjectSpec, {"kind": "cube", "size_m": None, "path": "", "scale": None, "position_m": []})
    assert blank == ObjectSpec(kind="cube")  # null, "" and [] mean "not given" (launch arguments left empty)
    q = load(ObjectSpec, {"kind": "box", "size_m": [0.1, 0.05, 0.02], "quaternion_wxyz": [1, 0, 0, 1e-4]})
    np.testing.assert_allclose(np.linalg.norm(q.quaternion_wxyz), 1.0, atol=1e-15)


@pytest.mark.parametrize(
    ("d", "fragment"),
    [
        ({"kind": "cube", "colour": "red"}, "object.colour: unknown key 'colour'; known keys: kind, path, position_m"),
        ({"size_m": [0.1]}, "object: missing required key 'kind'"),
        ({"kind": "pyramid"}, "object.kind: expected one of ['cube', 'rubiks_cube', 'box', 'sphere', "),
        ({"kind": "box", "size_m": [0.1, 0.1]}, "needs 3 value(s) (x, y, z)"),
        ({"kind": "sphere", "size_m": [-0.1]}, "object.size_m[0]: expected a finite number > 0, got -0.1"),
        ({"kind": "sphere", "size_m": [float("nan")]}, "object.size_m[0]: expected a finite number > 0, got nan"),
        ({"kind": "cube", "size_m": [50]}, "millimetres given as metres"),
        ({"kind": "torus", "size_m": [0.01, 0.02]}, "minor radius < major radius"),
        ({"kind": "rubiks_cube", "size_m": [0.06]}, "fixed at 57 mm"),
        ({"kind": "mesh"}, "needs a path"),
        ({"kind": "cube", "path": "a.stl"}, "only kind 'mesh' takes a path"),
        ({"kind": "mesh", "path": "a.stl", "scale": 0}, "object.scale: expected a finite number > 0, got 0"),
        ({"kind": "mesh", "path": ""}, "object: no path given: kind 'mesh' needs a path to a mesh file"),
        ({"kind": "mesh"}, "object: no path given: kind 'mesh' needs a path to a mesh file"),
        ({"kind": "cube", "position_m": [0, 0]}, "object.position_m: expected 3 items, got [0, 0]"),
        ({"kind": "cube", "position_m": [0, 0, math.inf]}, "object.position_m[2]: expected a finite number, got inf"),
        ({"kind": "cube", "quaternion_wxyz": [0, 0, 0, 0]}, "object: quaternion_wxyz = [0.0, 0.0, 0.0, 0.0]: norm 0"),
        ({"kind": "cube", "position_m": "origin"}, "object.position_m: expected a list, got 'origin'"),
    ],
)
def test_load_rejects_bad_input_naming_key_and_value(d: dict, fragment: str) -> None:
    with pytest.raises(ConfigError) as info:
        load(ObjectSpec, d, "scenes/x.yaml: object")
    assert "scenes/x.yaml" in str(info.value)
    assert fragment in str(info.value)


# --- primitives ------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("d", "volume", "extents"),
    [
        ({"kind": "cube"}, 0.05**3, (0.05, 0.05, 0.05)),
        ({"kind": "rubiks_cube"}, RUBIKS_CUBE_EDGE_M**3, (0.057,) * 3),
        ({"kind": "box", "size_m": [0.1, 0.06, 0.02]}, 0.1 * 0.06 * 0.02, (0.1, 0.06, 0.02)),
        ({"kind": "sphere", "size_m": [0.03]}, 4 / 3 * math.pi * 0.03**3, (0.06,) * 3),
        ({"kind": "cylinder", "size_m": [0.02, 0.08]}, math.pi * 0.02**2 * 0.08, (0.04, 0.04, 0.08)),
        ({"kind": "torus", "size_m": [0.04, 0.012]}, 2 * math.pi**2 * 0.04 * 0.012**2, (0.104, 0.104, 0.024)),
    ],
)
def test_primitives_are_watertight_with_the_right_size(d: dict, volume: float, extents: tuple) -> None:
    model = load_object(load(ObjectSpec, d))
    assert model.watertight and model.mesh.is_watertight
    assert model.name == d["kind"]
    assert model.convex == (d["kind"] != "torus")
    # tessellated curved surfaces lie inside the true one: volume within 1 %, extents within 0.2 %
    np.testing.assert_allclose(model.mesh.volume, volume, rtol=1e-2)
    np.testing.assert_allclose(np.sort(model.mesh.extents), np.sort(extents), rtol=2e-3)
    np.testing.assert_allclose(model.mesh.bounds.mean(axis=0), 0.0, atol=1e-12)


def test_torus_lies_in_the_xy_plane() -> None:
    mesh = load_object(ObjectSpec(kind="torus", size_m=(0.04, 0.01))).mesh
    np.testing.assert_allclose(mesh.extents, [0.1, 0.1, 0.02], rtol=1e-3)


def test_pose_is_applied_in_the_world_frame() -> None:
    half = math.sqrt(0.5)  # 90 deg about z
    spec = ObjectSpec(
        kind="box", size_m=(0.1, 0.04, 0.02), position_m=(0.3, -0.2, 0.1), quaternion_wxyz=(half, 0, 0, half)
    )
    mesh = load_object(spec).mesh
    np.testing.assert_allclose(mesh.bounds.mean(axis=0), [0.3, -0.2, 0.1], atol=1e-12)
    np.testing.assert_allclose(mesh.extents, [0.04, 0.1, 0.02], atol=1e-12)


@pytest.mark.parametrize(
    ("d", "geom_type", "size"),
    [
        ({"kind": "cube", "size_m": [0.04]}, mujoco.mjtGeom.mjGEOM_BOX, [0.02, 0.02, 0.02]),
        ({"kind": "rubiks_cube"}, mujoco.mjtGeom.mjGEOM_BOX, [0.0285] * 3),
        ({"kind": "box", "size_m": [0.1, 0.06, 0.02]}, mujoco.mjtGeom.mjGEOM_BOX, [0.05, 0.03, 0.01]),
        ({"kind": "sphere", "size_m": [0.03]}, mujoco.mjtGeom.mjGEOM_SPHERE, [0.03, 0, 0]),
        ({"kind": "cylinder", "size_m": [0.02, 0.08]}, mujoco.mjtGeom.mjGEOM_CYLINDER, [0.02, 0.04, 0]),
    ],
)
def test_primitive_mjcf_is_a_native_geom_at_the_pose(d: dict, geom_type: int, size: list) -> None:
    d = {**d, "position_m": [0.1, 0.2, 0.3], "quaternion_wxyz": [0, 1, 0, 0]}
    model = load_object(load(ObjectSpec, d))
    assets, geoms = model.mjcf_assets_and_geoms()
    assert assets == ""
    m = _model(assets, geoms)
    g = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "object")
    assert m.geom_type[g] == geom_type
    np.testing.assert_allclose(m.geom_size[g], size, atol=1e-12)
    np.testing.assert_allclose(m.geom_pos[g], [0.1, 0.2, 0.3], atol=1e-12)
    np.testing.assert_allclose(m.geom_quat[g], [0, 1, 0, 0], atol=1e-12)


def test_torus_mjcf_mesh_matches_the_world_frame_mesh() -> None:
    model = load_object(ObjectSpec(kind="torus", size_m=(0.04, 0.012), position_m=(0.2, 0.0, 0.05)))
    assets, geoms = model.mjcf_assets_and_geoms()
    assert model.geom_names() == ("object",)
    m = _model(assets, geoms)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    g = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "object")
    vert = m.mesh_vert[: m.mesh_vertnum[0]] @ d.geom_xmat[g].reshape(3, 3).T + d.geom_xpos[g]
    # MuJoCo stores vertices in float32
    np.testing.assert_allclose(vert.min(axis=0), model.mesh.bounds[0], atol=1e-6)
    np.testing.assert_allclose(vert.max(axis=0), model.mesh.bounds[1], atol=1e-6)


@pytest.mark.slow  # CoACD takes 2-6 s even on a coarse torus
def test_decomposed_torus_lets_a_probe_sit_in_the_hole(monkeypatch: pytest.MonkeyPatch) -> None:
    """MuJoCo's hull of a torus fills its hole; the CoACD parts do not."""
    mesh = trimesh.creation.torus(0.04, 0.012, major_sections=24, minor_sections=12)
    parts = convex_decomposition(mesh)
    assert len(parts) >= 4
    assert all(part.is_convex for part in parts)
    np.testing.assert_allclose(convex_decomposition(mesh)[0].vertices, parts[0].vertices)  # from cache
    probe = '<body pos="0 0 0"><freejoint/><geom type="sphere" size="0.008"/></body>'
    model = load_object(ObjectSpec(kind="torus", size_m=(0.04, 0.012)))
    # the coarse parts above stand in for those of the fine torus, to keep the test fast
    monkeypatch.setattr("palpate.nodes.sim.decomposition.convex_decomposition", lambda mesh: parts)
    counts: dict[str, int] = {}
    for collision in ("hull", "decomposed"):
        m = _model(*model.mjcf_assets_and_geoms(collision), extra=probe)
        d = mujoco.MjData(m)
        mujoco.mj_forward(m, d)
        counts[collision] = d.ncon
    assert counts == {"hull": 1, "decomposed": 0}
    assert len(model.geom_names("decomposed")) == len(parts)


# --- sampling --------------------------------------------------------------------------------------
def test_sample_surface_is_uniform_by_area_and_on_the_surface() -> None:
    mesh = load_object(ObjectSpec(kind="box", size_m=(0.1, 0.05, 0.02))).mesh
    count = 20_000
    points, normals = sample_surface(mesh, count, np.random.default_rng(1))
    assert points.shape == normals.shape == (count, 3)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-12)
    closest = ExactContactSensor(mesh).closest(points)
    np.testing.assert_allclose(closest.distance_m, 0.0, atol=1e-12)
    # fraction of samples on the +-x, +-y, +-z faces vs their area share, within 4 standard errors
    axis = np.argmax(np.abs(normals), axis=1)
    area = np.array([0.05 * 0.02, 0.1 * 0.02, 0.1 * 0.05])
    share = area / area.sum()
    observed = np.bincount(axis, minlength=3) / count
    np.testing.assert_array_less(np.abs(observed - share), 4 * np.sqrt(share * (1 - share) / count))
    # points are uniform inside faces: the mean of the +z face samples is its centre
    top = points[normals[:, 2] > 0.5]
    np.testing.assert_allclose(top[:, :2].mean(axis=0), 0.0, atol=4 * 0.1 / math.sqrt(12 * len(top)))


def test_sample_surface_is_reproducible() -> None:
    mesh = load_object(ObjectSpec(kind="sphere", size_m=(0.02,))).mesh
    a = sample_surface_faces(mesh, 50, np.random.default_rng(5))
    b = sample_surface_faces(mesh, 50, np.random.default_rng(5))
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)


# --- mesh files and bad input -------------------------------------------------------------------
@pytest.mark.ycb
def test_ycb_mesh_loads_by_id(ycb: Path) -> None:
    model = load_object(load(ObjectSpec, {"kind": "mesh", "path": "ycb:011_banana"}))
    assert model.name == "011_banana"
    assert model.watertight and not model.convex
    assert model.source_path == ycb / "011_banana.stl"
    np.testing.assert_allclose(model.mesh.extents, [0.10894, 0.17845, 0.03674], atol=2e-5)


def test_mesh_file_in_metres_loads_with_scale(tmp_path: Path) -> None:
    path = tmp_path / "box_mm.stl"
    trimesh.creation.box(extents=[40.0, 30.0, 20.0]).export(path)
    model = load_object(_mesh_spec(path, scale=0.001))
    np.testing.assert_allclose(model.mesh.extents, [0.04, 0.03, 0.02], atol=1e-12)
    assert model.convex and model.name == "box_mm"
    assets, geoms = model.mjcf_assets_and_geoms()
    assert 'type="mesh"' in geoms and ".stl" in assets
    _model(assets, geoms)


def test_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "nope.stl"
    with pytest.raises(MeshError, match=r"nope\.stl: mesh file not found .*check object\.path"):
        load_object(_mesh_spec(path))


def test_unreadable_path_is_a_directory(tmp_path: Path) -> None:
    path = tmp_path / "dir.stl"
    path.mkdir()
    with pytest.raises(MeshError, match=r"dir\.stl: cannot read the mesh: it is not a regular file"):
        load_object(_mesh_spec(path))


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root reads any file")
def test_unreadable_file_permissions(tmp_path: Path) -> None:
    path = tmp_path / "locked.stl"
    trimesh.creation.box(extents=[0.1] * 3).export(path)
    path.chmod(0)
    with pytest.raises(MeshError, match=r"locked\.stl: cannot read the mesh file .*check its permissions"):
        load_object(_mesh_spec(path))


@pytest.mark.parametrize(
    ("name", "content", "fragment"),
    [
        ("notes.txt", b"hello", r"not a mesh file \(extension '\.txt' is not a mesh format\); convert it"),
        ("garbage.stl", b"this is not an STL file at all", r"not a mesh: the STL file holds no vertices"),
        ("garbage.ply", b"hello", r"not a readable PLY mesh .*re-export it as a triangle mesh"),
        (
            "cloud.ply",
            b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
            b"property float z\nend_header\n0 0 0\n1 0 0\n0 1 0\n",
            r"holds 3 points but no triangles \(a point cloud",
        ),
    ],
)
def test_file_that_is_not_a_mesh(tmp_path: Path, name: str, content: bytes, fragment: str) -> None:
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(MeshError, match=fragment) as info:
        load_object(_mesh_spec(path))
    assert str(path) in str(info.value)


def test_degenerate_flat_mesh(tmp_path: Path) -> None:
    path = tmp_path / "flat.stl"
    v = [[0, 0, 0], [0.1, 0, 0], [0.1, 0.1, 0], [0, 0.1, 0]]
    trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3], [0, 2, 1], [0, 3, 2]], process=False).export(path)
    # a two-sided square: its back faces repeat the front ones, and what is left encloses nothing
    with (
        pytest.warns(MeshWarning, match=r"flat\.stl: 2 triangles repeat others"),
        pytest.raises(MeshError, match=r"flat\.stl: degenerate mesh: zero volume .*export the object's closed"),
    ):
        load_object(_mesh_spec(path))


def test_a_flat_mesh_at_a_tilt_is_degenerate_too(tmp_path: Path) -> None:
    """A mesh fuzzer's find: flatness was judged on the axis-aligned box, so a tilted flat disc passed."""
    sphere = trimesh.creation.icosphere(2, radius=0.05)
    vertices = sphere.vertices.copy()
    vertices[:, 2] = 0.0
    disc = trimesh.Trimesh(vertices, sphere.faces, process=False)
    disc.apply_transform(trimesh.transformations.rotation_matrix(0.7, [1, 1, 0]))
    disc.export(tmp_path / "tilted.stl")  # float32 coordinates: the plane holds to about 1e-9 m
    with pytest.warns(MeshWarning), pytest.raises(MeshError, match=r"tilted\.stl: degenerate mesh: zero volume"):
        load_object(_mesh_spec(tmp_path / "tilted.stl"))


@pytest.mark.parametrize(
    ("name", "text", "fragment"),
    [
        ("out.ply", "3 1 2 77", r"1 triangles name a vertex index outside 0\.\.3 \(e\.g\. 77\)"),
        ("negative.ply", "3 -1 2 3", r"1 triangles name a vertex index outside 0\.\.3 \(e\.g\. -1\)"),
    ],
)
def test_a_ply_face_beyond_its_vertices_is_refused(tmp_path: Path, name: str, text: str, fragment: str) -> None:
    """The PLY reader keeps such indices: 77 raised an IndexError, -1 silently meant the last vertex."""
    header = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
    body = "element face 2\nproperty list uchar int vertex_indices\nend_header\n"
    points = "0 0 0\n0.1 0 0\n0 0.1 0\n0 0 0.1\n"
    (tmp_path / name).write_text(header + body + points + f"3 0 1 2\n{text}\n")
    with pytest.raises(MeshError, match=rf"{name}: corrupt mesh: {fragment}"):
        load_object(_mesh_spec(tmp_path / name))


def test_a_fan_the_contact_sensor_cannot_hold_is_refused_naming_the_file(tmp_path: Path) -> None:
    """A mesh fuzzer's find: the face rings' limit came up only when a run built its sensor, without the
    file's name (bench contacts), or once per run (an evaluation)."""
    trimesh.creation.cylinder(radius=0.03, height=0.1, sections=1500).export(tmp_path / "fan.stl")
    with pytest.raises(MeshError, match=r"fan\.stl: 6,000 faces with a vertex shared by 1500 of them"):
        load_object(_mesh_spec(tmp_path / "fan.stl"))
    trimesh.creation.cylinder(radius=0.03, height=0.1, sections=200).export(tmp_path / "cylinder.stl")
    assert len(load_object(_mesh_spec(tmp_path / "cylinder.stl")).mesh.faces) == 800


def test_a_regular_mesh_of_too_many_faces_is_refused_as_such(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """An outside walkthrough: a regular 1M-face torus was refused as "a fan, as CAD tools export round caps"."""
    from palpate.nodes.sim import objects

    monkeypatch.setattr(objects, "MAX_RING_ENTRIES", 10_000)  # a million faces' worth, scaled down
    trimesh.creation.icosphere(subdivisions=4, radius=0.03).export(tmp_path / "fine.stl")
    with pytest.raises(MeshError) as info:
        load_object(_mesh_spec(tmp_path / "fine.stl"))
    assert "fine.stl: 5,120 faces are too many for the contact sensor: with up to 6 faces at a vertex it takes at " in (
        str(info.value)
    )
    assert "at most 555; simplify the mesh" in str(info.value) and "fan" not in str(info.value)


def test_an_obj_of_two_dimensional_vertices_is_refused(tmp_path: Path) -> None:
    (tmp_path / "flat2d.obj").write_text("v 1 2\nv 0 0\nv 1 1\nf 1 2 3\n")
    with pytest.raises(MeshError, match=r"flat2d\.obj: not a 3-D triangle mesh \(vertices of shape \(3, 2\)"):
        load_object(_mesh_spec(tmp_path / "flat2d.obj"))


def test_degenerate_zero_area_mesh(tmp_path: Path) -> None:
    path = tmp_path / "needles.obj"
    path.write_text("v 0 0 0\nv 0.1 0 0\nv 0.2 0 0\nf 1 2 3\n")
    with pytest.raises(MeshError, match=r"needles\.obj: degenerate mesh: all triangles have zero area"):
        load_object(_mesh_spec(path))


#: What the message says of the limits, whichever is passed (a 3 m object in millimetres is too large too).
HOLD = r": the scenes hold objects 2 mm to 2 m across\)"


@pytest.mark.parametrize(
    ("extent", "scale", "fragment"),
    [
        (
            150.0,
            1.0,
            r"150 m across after scale 1 \(over 2 m" + HOLD + r"; a file in millimetres\? Give it a scale of 0\.001 "
            r"\(15 cm across\): .*--scale 0\.001 for palpate eval explore",
        ),
        (
            0.1,
            0.001,
            r"0\.0001 m across after scale 0\.001 \(under 2 mm" + HOLD + r"; a file in metres\? .*scale of 1 \(10 cm",
        ),
        # an outside walkthrough: a 1.5 m box in millimetres was told of centimetres and inches, and with
        # --scale 0.01 to take 0.00001 (a 1.5 cm object, accepted without a word): the hint now reads the
        # file's own extent, and 1.5 m is held though not within 5 mm to 1 m
        (1500.0, 1.0, r"; a file in millimetres\? Give it a scale of 0\.001 \(1\.5 m across\)"),
        (1500.0, 0.01, r"15 m across after scale 0\.01 .*; a file in millimetres\? Give it a scale of 0\.001 "),
    ],
)
def test_absurd_scale(tmp_path: Path, extent: float, scale: float, fragment: str) -> None:
    path = tmp_path / "big.stl"
    trimesh.creation.box(extents=[extent, extent / 2, extent / 3]).export(path)
    with pytest.raises(MeshError, match=fragment) as info:
        load_object(_mesh_spec(path, scale))
    assert "big.stl: absurd scale" in str(info.value)


def test_coordinates_near_1e30_are_an_absurd_scale_not_a_degenerate_mesh(tmp_path: Path) -> None:
    """trimesh's vertex merge overflowed first, and the mesh was called degenerate (an outside audit)."""
    path = tmp_path / "huge.obj"
    box = trimesh.creation.box(extents=[1.0, 1.0, 1.0])
    lines = [f"v {x:.6e} {y:.6e} {z:.6e}" for x, y, z in box.vertices * 1e30]
    path.write_text("\n".join(lines + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in box.faces]) + "\n")
    with pytest.raises(MeshError, match=r"huge\.obj: out of range: the mesh is 1e\+30 m across.* in no unit \(metres"):
        load_object(_mesh_spec(path))


def test_a_mesh_far_from_the_origin_is_refused_by_name(tmp_path: Path) -> None:
    """An outside walkthrough: a 6 cm sphere at x = 10 km passed every check, then the run failed as "the
    effector left the world" (launch) or on a probe start the user never set (eval explore)."""
    sphere = trimesh.creation.icosphere(radius=0.03)
    sphere.apply_translation([10_000.0, 0.0, 0.0])
    sphere.export(tmp_path / "far.stl")
    with pytest.raises(MeshError, match=r"far\.stl: the mesh lies 10000 m from the origin .*\(10000, 0, 0\) m"):
        load_object(_mesh_spec(tmp_path / "far.stl"))
    sphere.apply_translation([-9_100.0, 0.0, 0.0])  # 900 m out: within reach
    sphere.export(tmp_path / "near.stl")
    assert load_object(_mesh_spec(tmp_path / "near.stl")).mesh.bounds[1, 0] == pytest.approx(900.03)


def test_a_file_several_units_could_explain_is_given_each_units_scale_and_size(tmp_path: Path) -> None:
    """A 3 m box: 3 mm in millimetres is held but small; 3 cm in centimetres and 7.62 cm in inches are
    plausible sizes, so those are offered, each with the size it gives, and no scale off by a factor."""
    path = tmp_path / "crate.stl"
    trimesh.creation.box(extents=[3.0] * 3).export(path)
    with pytest.raises(MeshError) as info:
        load_object(_mesh_spec(path))
    message = str(info.value)
    assert "crate.stl: absurd scale" in message and "which unit is the file in?" in message
    assert "0.01 for centimetres (3 cm across), 0.0254 for inches (7.62 cm across)" in message
    assert "0.001" not in message


def test_a_primitive_too_large_for_any_unit_mistake_is_not_told_to_shrink_a_thousandfold() -> None:
    with pytest.raises(ConfigError) as info:
        load(ObjectSpec, {"kind": "box", "size_m": [3, 3, 3]}, "scenes/x.yaml: object")
    assert "3 m across" in str(info.value) and "no factor of 1000 makes it 5 mm to 1 m" in str(info.value)
    assert "size_m: [0.003" not in str(info.value)


def test_non_watertight_mesh_warns_what_it_affects(tmp_path: Path) -> None:
    path = tmp_path / "open_box.stl"
    box = trimesh.creation.box(extents=[0.1, 0.1, 0.1])
    trimesh.Trimesh(box.vertices, box.faces[:-2]).export(path)  # drop the two triangles of one side
    with pytest.warns(MeshWarning, match=r"open_box\.stl: mesh is not watertight \(4 open edges, 0 edges on") as record:
        model = load_object(_mesh_spec(path))
    message = str(record[0].message)
    assert "signed distance" in message and "inside/outside" in message and "volume-based metrics" in message
    assert not model.watertight


def test_a_mesh_of_separate_bodies_warns_that_coverage_counts_them_all(tmp_path: Path) -> None:
    path = tmp_path / "two.stl"
    cube = trimesh.creation.box(extents=[0.05, 0.05, 0.05])
    ball = trimesh.creation.icosphere(radius=0.025).apply_translation([0.1, 0.0, 0.0])
    trimesh.util.concatenate([cube, ball]).export(path)
    two_bodies = r"two\.stl: the mesh holds 2 separate bodies \(unconnected surfaces\); .*cap the coverage"
    with pytest.warns(MeshWarning, match=two_bodies):
        load_object(_mesh_spec(path))


def test_inward_wound_mesh_is_inverted_with_a_warning(tmp_path: Path) -> None:
    path = tmp_path / "inside_out.stl"
    box = trimesh.creation.box(extents=[0.1, 0.1, 0.1])
    trimesh.Trimesh(box.vertices, box.faces[:, ::-1]).export(path)
    with pytest.warns(MeshWarning, match=r"inside_out\.stl: faces are wound inward"):
        model = load_object(_mesh_spec(path))
    assert model.mesh.volume > 0


def test_one_inward_body_among_others_is_turned_out_and_a_cavity_kept(tmp_path: Path) -> None:
    """An outside walkthrough: a ball wound inward beside a cube passed (the whole volume is positive), and
    the probe read inward normals on it: 34 % coverage after 200 contacts instead of 80 %."""
    cube = trimesh.creation.box(extents=[0.05, 0.05, 0.05])
    beside = trimesh.creation.icosphere(radius=0.02).apply_translation([0.05, 0.0, 0.0])
    beside.invert()
    path = tmp_path / "beside.stl"
    trimesh.util.concatenate([cube, beside]).export(path)
    with pytest.warns(MeshWarning, match=r"beside\.stl: 1 of the mesh's 2 bodies are wound inward"):
        mesh = load_object(_mesh_spec(path)).mesh
    assert [body.volume > 0 for body in mesh.split(only_watertight=False)] == [True, True]
    cavity = trimesh.creation.icosphere(radius=0.01)
    cavity.invert()  # a hollow cube: the cavity's faces point into it, as they should
    path = tmp_path / "hollow.stl"
    trimesh.util.concatenate([cube, cavity]).export(path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        mesh = load_object(_mesh_spec(path)).mesh
    assert not [w for w in caught if "wound inward" in str(w.message)]
    assert sorted(body.volume > 0 for body in mesh.split(only_watertight=False)) == [False, True]
    ball = trimesh.creation.icosphere(radius=0.004)
    ball.invert()  # an inward ball inside the cavity: in empty space, so turned out (a review's case)
    path = tmp_path / "ball_in_cavity.stl"
    trimesh.util.concatenate([cube, cavity, ball]).export(path)
    with pytest.warns(MeshWarning, match=r"ball_in_cavity\.stl: 1 of the mesh's 3 bodies are wound inward"):
        mesh = load_object(_mesh_spec(path)).mesh
    assert sorted(body.volume > 0 for body in mesh.split(only_watertight=False)) == [False, True, True]


def test_bodies_wound_both_ways_whose_volumes_cancel_are_read_and_turned_out(tmp_path: Path) -> None:
    """An outside walkthrough: a grid of cubes, every other one inverted, was refused as "zero volume ...
    flat or collapsed" when the volumes cancelled (and 2,500 cubes took 37 s to orient; 0.6 s now)."""
    cubes = [
        trimesh.creation.box((0.004,) * 3).apply_translation([0.006 * i, 0.006 * j, 0.0])
        for i in range(4)
        for j in range(4)
    ]
    for cube in cubes[1::2]:
        cube.invert()
    path = tmp_path / "grid.stl"
    trimesh.util.concatenate(cubes).export(path)
    with pytest.warns(MeshWarning, match=r"grid\.stl: 8 of the mesh's 16 bodies are wound inward"):
        mesh = load_object(_mesh_spec(path)).mesh
    assert all(body.volume > 0 for body in mesh.split(only_watertight=False))


def test_duplicate_triangles_are_dropped_with_a_warning(tmp_path: Path) -> None:
    # a repeated triangle would count twice in the area, the covering bound and the budgets
    path = tmp_path / "twice.stl"
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.03)
    trimesh.Trimesh(sphere.vertices, np.vstack([sphere.faces, sphere.faces[:10]]), process=False).export(path)
    with pytest.warns(MeshWarning, match=r"twice\.stl: 10 triangles repeat others"):
        model = load_object(_mesh_spec(path))
    assert len(model.mesh.faces) == len(sphere.faces)
    assert model.mesh.area == pytest.approx(sphere.area)
    assert model.watertight


def test_inconsistently_wound_faces_are_rewound_with_a_warning(tmp_path: Path) -> None:
    # half the triangles clockwise: watertight, but the volume nearly cancels and normals point both ways
    path = tmp_path / "mixed.stl"
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.03)
    faces = sphere.faces.copy()
    faces[::2] = faces[::2, ::-1]
    trimesh.Trimesh(sphere.vertices, faces, process=False).export(path)
    with pytest.warns(MeshWarning, match=r"mixed\.stl: faces are wound inconsistently"):
        model = load_object(_mesh_spec(path))
    assert model.mesh.is_winding_consistent
    assert model.mesh.volume == pytest.approx(sphere.volume, rel=1e-6)  # STL holds float32
    # two bodies, each mixed: each is wound outward on its own (one winding for all would turn one inward)
    other = sphere.copy()
    other.apply_translation([0.1, 0.0, 0.0])
    both = trimesh.util.concatenate([sphere, other])
    faces = both.faces.copy()
    faces[::3] = faces[::3, ::-1]
    trimesh.Trimesh(both.vertices, faces, process=False).export(path)
    with pytest.warns(MeshWarning) as record:
        mesh = load_object(_mesh_spec(path)).mesh
    assert ["wound inconsistently" in str(w.message) for w in record] == [True, False]  # then: 2 bodies
    assert [part.volume for part in mesh.split(only_watertight=True)] == pytest.approx([sphere.volume] * 2, rel=1e-6)
    # a hollow ball whose outer faces are mixed: re-winding keeps the cavity a cavity (it turned its faces
    # outward, a solid ball inside the hollow one; session 42's review), and leaves a ball in it solid
    cavity = trimesh.creation.icosphere(subdivisions=2, radius=0.015)
    cavity.invert()
    ball = trimesh.creation.icosphere(subdivisions=1, radius=0.005)
    hollow = trimesh.util.concatenate([sphere, cavity, ball])
    faces = hollow.faces.copy()
    faces[: len(sphere.faces) : 2] = faces[: len(sphere.faces) : 2, ::-1]
    trimesh.Trimesh(hollow.vertices, faces, process=False).export(path)
    with pytest.warns(MeshWarning, match=r"mixed\.stl: faces are wound inconsistently"):
        mesh = load_object(_mesh_spec(path)).mesh
    volumes = sorted(part.volume for part in mesh.split(only_watertight=True))
    assert volumes == pytest.approx([cavity.volume, ball.volume, sphere.volume], rel=1e-6)
    # two balls that overlap in part, one of them mixed: both stay solid (the one is no cavity)
    overlapping = trimesh.util.concatenate([sphere, sphere.copy().apply_translation([0.02, 0.0, 0.0])])
    faces = overlapping.faces.copy()
    faces[::2] = faces[::2, ::-1]
    trimesh.Trimesh(overlapping.vertices, faces, process=False).export(path)
    with pytest.warns(MeshWarning, match=r"mixed\.stl: faces are wound inconsistently"):
        mesh = load_object(_mesh_spec(path)).mesh
    assert [part.volume > 0 for part in mesh.split(only_watertight=True)] == [True, True]


def test_a_mesh_over_mujocos_stl_limit_gives_mujoco_its_convex_hull(monkeypatch: pytest.MonkeyPatch) -> None:
    # MuJoCo reads at most 200,000 triangles from an STL file and collides a mesh geom as its hull
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.03)  # 1280 triangles
    assert mujoco_hull_mesh(mesh) is mesh
    monkeypatch.setattr(objects, "MUJOCO_MAX_STL_FACES", 1000)
    hull = mujoco_hull_mesh(mesh)
    assert len(hull.faces) <= 1000 and hull.is_convex
    assert hull.volume == pytest.approx(mesh.volume, rel=0.05)  # every k-th hull vertex: a little inside
    ring = trimesh.creation.annulus(r_min=0.02, r_max=0.03, height=0.01, sections=400)  # not convex
    monkeypatch.setattr(objects, "MUJOCO_MAX_STL_FACES", len(ring.faces) - 1)
    assert mujoco_hull_mesh(ring).volume == pytest.approx(ring.convex_hull.volume)


def test_the_hull_of_a_finely_divided_cylinder_is_quick_and_small(monkeypatch: pytest.MonkeyPatch) -> None:
    """An outside walkthrough: a CAD cylinder of 62,500 sections (250,000 triangles, all vertices on two
    circles) kept qhull's facet merging busy for minutes, and MuJoCo's own hull of 18,000 such vertices took
    24 s."""
    import time

    cylinder = trimesh.creation.cylinder(radius=0.02, height=0.05, sections=20_000)
    monkeypatch.setattr(objects, "MUJOCO_MAX_STL_FACES", 50_000)
    start = time.perf_counter()
    hull = mujoco_hull_mesh(cylinder)
    assert time.perf_counter() - start < 20.0  # about 1 s; the default qhull options took minutes
    assert len(hull.vertices) <= objects.MUJOCO_MAX_HULL_VERTICES and hull.is_watertight
    assert hull.volume == pytest.approx(cylinder.volume, rel=1e-3)


def test_two_boxes_sharing_an_edge_are_not_watertight_for_that_edge(tmp_path: Path) -> None:
    path = tmp_path / "edge.stl"
    first = trimesh.creation.box(extents=(0.04, 0.04, 0.04))
    second = first.copy()
    second.apply_translation([0.04, 0.04, 0.0])  # touches the first along one vertical edge
    trimesh.util.concatenate([first, second]).export(path)
    with pytest.warns(MeshWarning, match=r"not watertight \(0 open edges, \d+ edges on more than two triangles\)"):
        load_object(_mesh_spec(path))


def test_sampled_surface_points_are_on_the_surface() -> None:
    mesh = load_object(ObjectSpec(kind="sphere", size_m=(0.03,))).mesh
    points, normals = sample_surface(mesh, 1000, np.random.default_rng(6))
    closest = ExactContactSensor(mesh).closest(points + 1e-3 * normals)
    np.testing.assert_allclose(closest.distance_m, 1e-3, atol=1e-12)
    np.testing.assert_allclose(closest.normals, normals, atol=1e-12)


def test_the_command_line_prints_a_mesh_warning_as_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    """An outside walkthrough: it came in Python's form, with our source file, line and code."""
    import warnings

    from palpate import cli

    shown_as_before: list[str] = []
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        warnings.showwarning = lambda message, *rest: shown_as_before.append(str(message))
        cli._show_mesh_warnings("launch")
        installed = warnings.showwarning
        cli._show_mesh_warnings("eval")  # once installed: a second command (tests, one process) only renames
        assert warnings.showwarning is installed  # not wrapped again at each call
        warnings.warn(MeshWarning("x.stl: the mesh holds 2 separate bodies"), stacklevel=1)
        warnings.warn(UserWarning("another library's"), stacklevel=1)
    assert capsys.readouterr().err == "palpate eval: warning: x.stl: the mesh holds 2 separate bodies\n"
    assert shown_as_before == ["another library's"]  # the others as Python shows them


@pytest.mark.parametrize("size_m", [(0.001, 0.0004), (0.004, 0.0015)])
def test_a_small_torus_keeps_every_face(size_m: tuple[float, float]) -> None:
    """An outside walkthrough: trimesh merged the vertices of small tori: one of 1 mm major radius had no
    face (a traceback at launch), one 11 mm across had 13,056 of its 16,384 (holes in the evaluators' truth)."""
    from palpate.nodes.sim.objects import TORUS_MAJOR_SECTIONS, TORUS_MINOR_SECTIONS, primitive_mesh

    mesh = primitive_mesh("torus", size_m)
    assert len(mesh.faces) == 2 * TORUS_MAJOR_SECTIONS * TORUS_MINOR_SECTIONS and mesh.is_watertight
    assert mesh.extents == pytest.approx([2 * sum(size_m), 2 * sum(size_m), 2 * size_m[1]], rel=0.01)
