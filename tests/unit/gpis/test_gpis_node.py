"""GPIS node: a touch it cannot use (beyond the sanity bounds, a normal that is no unit vector, or too far
from the contacts for the kernel) is refused before the GP changes; a request must name 'global'."""

from __future__ import annotations

import numpy as np
import pytest

from palpate.errors import InputError
from palpate.messages.base import Message
from palpate.messages.schemas import SurfaceMesh, SurfaceRequest, TouchEvent
from palpate.nodes.gpis.core import GPIS
from palpate.nodes.gpis.local import AutoGPIS
from palpate.nodes.gpis.node import GPISNode, GPISNodeConfig
from palpate.runtime.node import NodeContext


def touch(position: list[float], normal: list[float]) -> TouchEvent:
    return TouchEvent(
        stamp_ns=0,
        index=0,
        position_m=np.array(position),
        normal=np.array(normal),
        approach_direction=np.array([0.0, 0.0, -1.0]),
        predicted_contact_m=np.full(3, np.nan),
        missed=False,
        travelled_m=0.0,
        rotation_deg=0.0,
    )


def test_unusable_touches_leave_the_gp_unchanged() -> None:
    sent: list[Message] = []
    ctx = NodeContext("gpis", 0, lambda topic, message: sent.append(message), {"surface": "surface/mesh"})
    node = GPISNode(GPISNodeConfig(), ctx)
    node.on_touches(touch([0.0, 0.0, 0.03], [0.0, 0.0, 1.0]))
    exact = node.gp.estimator if isinstance(node.gp, AutoGPIS) else None
    assert isinstance(exact, GPIS)  # "auto": the exact GP while the contacts are few
    factor = exact.cholesky_factor()
    cases = [
        (touch([0.0, 0.0, 1e300], [0.0, 0.0, 1.0]), r"^position_m: coordinate 1e\+300 m lies beyond"),
        (touch([0.01, 0.0, 0.03], [0.0, 0.0, 1e-200]), r"^normal: norm 1e-200, not 1"),
        (touch([0.01, 0.0, 0.03], [0.0, 0.0, 0.0]), r"^normal: norm 0, not 1"),
        # R_m = 0.5 m: the local grid around a touch 0.45 m away would reach 0.55 m from the first one
        (touch([0.45, 0.0, 0.03], [1.0, 0.0, 0.0]), r"^position_m: the GPIS cannot add this touch to its 1 contacts"),
    ]
    for message, reason in cases:
        with pytest.raises(InputError, match=reason):
            node.on_touches(message)
        assert node.gp.n_contacts == 1
        np.testing.assert_array_equal(exact.cholesky_factor(), factor)
    node.on_touches(touch([0.3, 0.0, 0.03], [1.0, 0.0, 0.0]))  # 0.3 m away still fits
    assert node.gp.n_contacts == 2 and len(sent) == 2
    with pytest.raises(InputError, match=r"^region: 'local' is no region a request can name; use 'global'"):
        node.on_request(SurfaceRequest(stamp_ns=0, region="local", variance=True))
    node.on_request(SurfaceRequest(stamp_ns=0, region="global", variance=True))
    assert isinstance(sent[-1], SurfaceMesh) and sent[-1].region == "global"
    with_variance = sent[-1]
    assert len(with_variance.variance_vertices) == len(with_variance.vertices_m) > 0
    node.on_request(SurfaceRequest(stamp_ns=0, region="global", variance=False))
    without = sent[-1]  # the same mesh, without Eq. 6
    assert isinstance(without, SurfaceMesh) and len(without.variance_vertices) == len(without.vertex_variance) == 0
    np.testing.assert_array_equal(without.vertices_m, with_variance.vertices_m)
    np.testing.assert_array_equal(without.faces, with_variance.faces)
