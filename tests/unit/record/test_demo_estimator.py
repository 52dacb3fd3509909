"""The demo's bounding-box estimator, whose re-run on a replayed log the integration tests compare."""

from __future__ import annotations

import logging

import numpy as np

from palpate.messages import codec
from palpate.messages.base import Message
from palpate.nodes.demo.core import BOX_FACES, box_mesh
from palpate.nodes.demo.node import BboxEstimator, BboxEstimatorConfig
from tests.unit.record.synthetic import contacts


def test_box_faces_are_wound_counter_clockwise_seen_from_outside() -> None:
    lower, upper = np.array([-1.0, -2.0, 0.5]), np.array([2.0, 1.0, 3.0])
    vertices, faces, normals = box_mesh(lower, upper)
    centre = (lower + upper) / 2
    assert faces.dtype == np.int32 and faces.shape == (12, 3) and np.array_equal(faces, BOX_FACES)
    for tri in faces:
        a, b, c = vertices[tri]
        normal = np.cross(b - a, c - a)
        assert np.dot(normal, (a + b + c) / 3 - centre) > 0
        assert np.count_nonzero(np.abs(normal) > 1e-12) == 1  # each triangle lies in a face plane
    # every edge is shared by exactly two triangles, in opposite directions (closed, consistently oriented)
    edges = {(int(t[i]), int(t[(i + 1) % 3])) for t in faces for i in range(3)}
    assert len(edges) == 36 and all((b, a) in edges for a, b in edges)
    np.testing.assert_allclose(vertices.min(axis=0), lower, atol=0)
    np.testing.assert_allclose(vertices.max(axis=0), upper, atol=0)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-15)
    np.testing.assert_allclose(np.sign(normals), np.sign(vertices - centre), atol=0)


class _Ctx:
    def __init__(self) -> None:
        self.sent: list[bytes] = []
        self.log = logging.getLogger("test")

    def publish(self, port: str, message: Message) -> None:
        assert port == "mesh"
        codec.validate(message)
        self.sent.append(codec.encode(message))


def test_estimator_publishes_the_box_of_all_contacts_after_each_tick_with_contacts() -> None:
    ctx = _Ctx()
    node = BboxEstimator(BboxEstimatorConfig(), ctx)
    node.on_tick(0)
    assert ctx.sent == []  # nothing before the first contact
    node.on_contacts(contacts(10, n=2, offset=0.0))
    node.on_contacts(contacts(10, n=1, offset=0.01))
    node.on_tick(10)
    node.on_contacts(contacts(20, n=0))
    node.on_tick(20)  # an empty contact set changes nothing: no new mesh
    assert len(ctx.sent) == 1
    mesh = codec.decode(ctx.sent[0])
    assert mesh.stamp_ns == 10 and mesh.num_contacts == 3
    np.testing.assert_allclose(mesh.vertices_m.min(axis=0), [0.0, 0.001, 0.002], atol=1e-15)
    np.testing.assert_allclose(mesh.vertices_m.max(axis=0), [0.010, 0.011, 0.012], atol=1e-15)
    np.testing.assert_allclose(mesh.vertex_variance, 0.010**2 / 12 / 3, rtol=1e-12)
