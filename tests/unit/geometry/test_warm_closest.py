"""The warm-started query (WarmClosest) answers as the exact sensor does, bit for bit, and its compiled
kernels compute what the Python-scalar code computes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from palpate.geometry import closest_kernels
from palpate.geometry.mesh_query import ExactContactSensor, WarmClosest, closest_region
from palpate.nodes.sim.objects import ObjectSpec, load_object, read_mesh_file


def _walks(mesh: trimesh.Trimesh, rng: np.random.Generator, walks: int, steps: int, height_m: float) -> np.ndarray:
    """Random walks (walks * steps, 3) starting ``height_m`` above surface samples, 0.1 mm per step."""
    points, faces = trimesh.sample.sample_surface(mesh, walks, seed=int(rng.integers(1 << 30)))
    out = []
    for p0, f in zip(points, faces, strict=True):
        p = p0 + height_m * mesh.face_normals[f]
        d = rng.normal(size=3)
        for _ in range(steps):
            d = d + 0.2 * rng.normal(size=3)
            d /= np.linalg.norm(d)
            p = p + 1e-4 * d
            out.append(p)
    return np.array(out)


def _assert_bitwise(sensor: ExactContactSensor, points: np.ndarray) -> WarmClosest:
    warm = WarmClosest(sensor)
    for p in points:
        point, distance, face = warm.query(p)
        expected = sensor.closest(p[None, :])
        assert point == tuple(expected.points_m[0].tolist())
        assert distance == float(expected.distance_m[0])
        # another face only on an exact tie: one at the same distance
        tri = sensor.mesh.triangles[[face, int(expected.face_ids[0])]]
        from palpate.geometry.mesh_query import closest_points_on_triangles

        q, _ = closest_points_on_triangles(np.repeat(p[None], 2, 0), tri[:, 0], tri[:, 1], tri[:, 2])
        np.testing.assert_allclose(np.linalg.norm(q - p, axis=1), abs(distance), rtol=0, atol=1e-15)
    return warm


def test_kernels_are_bitwise_twins_of_the_scalar_code() -> None:
    rng = np.random.default_rng(0)
    n = 4000
    a, b, c = (rng.normal(size=(n, 3)) * 0.01 for _ in range(3))
    p = 0.02 * rng.normal(size=(n, 3))
    p[::5] = a[::5] + 0.5 * (b[::5] - a[::5])  # points on an edge
    mesh = trimesh.Trimesh(np.concatenate([a, b, c]), np.arange(3 * n).reshape(3, n).T, process=False)
    sensor = ExactContactSensor(mesh)
    tri = sensor._triangles
    local = p - sensor._centre
    regions = set()
    for i in range(n):
        x, y, z = local[i].tolist()
        expected = sensor._project_scalar([x, y, z], i)
        got = closest_kernels.project(tri, i, x, y, z)
        assert got == expected
        regions.add(got[1])
        q, signed = sensor._finish_scalar([x, y, z], i, got[1], got[2], got[3])
        qx, qy, qz, dist, inside, weak = closest_kernels.finish(
            tri, sensor._sign_normals, i, got[1], got[2], got[3], x, y, z, 0.3, 0.1
        )
        assert (qx, qy, qz) == q
        assert dist == abs(signed)
        if not weak:
            assert (signed < 0) == inside
    assert len(regions) == 7
    d = rng.normal(size=(500, 6))
    for row in d.tolist():
        assert closest_kernels.closest_region(*row) == closest_region(*row)


@pytest.mark.parametrize(
    "spec",
    [
        ObjectSpec(kind="torus", size_m=(0.04, 0.012), position_m=(0.3, -0.2, 0.1)),
        ObjectSpec(kind="box", size_m=(0.1, 0.06, 0.04), position_m=(1.5, -1.0, 0.7)),
        ObjectSpec(kind="sphere", size_m=(0.03,)),
    ],
    ids=["torus", "box", "sphere"],
)
def test_warm_query_equals_the_sensor_along_walks(spec: ObjectSpec) -> None:
    mesh = load_object(spec).mesh
    sensor = ExactContactSensor(mesh)
    rng = np.random.default_rng(1)
    points = np.concatenate(
        [
            _walks(mesh, rng, 6, 120, 0.008),  # a fingertip sliding 8 mm above the surface
            _walks(mesh, rng, 3, 60, -0.002),  # inside, near the surface
            _walks(mesh, rng, 2, 60, 0.05),  # far: the sensor's own search
        ]
    )
    warm = _assert_bitwise(sensor, points)
    assert warm.counts["builds"] >= 9 and warm.counts["patch"] > 0.8 * len(points) and warm.counts["full"] > 0


def test_warm_query_rejects_non_finite_points() -> None:
    sensor = ExactContactSensor(load_object(ObjectSpec(kind="cube")).mesh)
    with pytest.raises(ValueError, match="finite"):
        WarmClosest(sensor).query([0.0, np.nan, 0.1])
    with pytest.raises(ValueError, match="reach_m"):
        WarmClosest(sensor, reach_m=0.0)


@pytest.mark.ycb
def test_warm_query_on_a_folded_scan_the_banana_and_the_fork(ycb: Path) -> None:
    rng = np.random.default_rng(2)
    for name in ("block_of_wood_6in.stl", "011_banana.stl", "030_fork.stl"):
        mesh = read_mesh_file(ycb / name)
        _assert_bitwise(ExactContactSensor(mesh), _walks(mesh, rng, 4, 100, 0.008))
