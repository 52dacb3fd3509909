"""Free space swept by the fingertip as the inequality f >= r (nodes/gpis/free_space.py)."""

from __future__ import annotations

import numpy as np
import pytest

from palpate.errors import EstimationError
from palpate.messages.base import Message
from palpate.messages.schemas import SurfaceMesh, SurfaceRequest
from palpate.nodes.gpis.core import GPIS, GPISConfig
from palpate.nodes.gpis.free_space import SweptSpace, enforce, most_broken_per_voxel, within_box
from palpate.nodes.gpis.local import AutoGPIS, LocalGPIS
from palpate.nodes.gpis.node import SPEC, GPISNode
from palpate.nodes.gpis.session import GPISNodeConfig
from palpate.runtime.node import NodeContext
from tests.unit.node_messages import no_contacts, pose, touch

R_TIP = 0.008
UP = np.array([0.0, 0.0, 1.0])


def plate_seen_from_above(spacing: float = 0.01) -> GPIS:
    """Contacts on the top of a 6 x 6 cm plate at z = 0 only: nothing says where its bottom is."""
    xs = np.arange(-0.03, 0.0301, spacing)
    X, Y = np.meshgrid(xs, xs)
    P = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    gp = GPIS(GPISConfig(), prior_centre_m=[0.0, 0.0, -0.005])
    gp.add_contacts(P, np.tile(UP, (len(P), 1)))
    return gp


def test_free_space_gradient_rows_carry_a_huge_multiple_of_the_prior_gradient_variance() -> None:
    gp = GPIS(GPISConfig(R_m=0.5), prior_centre_m=[0.0, 0.0, -0.005])
    gp.add_contact([0.0, 0.0, 0.0], UP)
    gp.add_free_space(np.array([[0.0, 0.0, 0.02]]), R_TIP)
    # thin plate, a = 1: Var grad f = 6 a R = 3; the free point's gradient rows add 1e6 x that as noise
    diag = np.diag(gp.observation_covariance())
    np.testing.assert_allclose(diag[5:8], 3.0 * (1.0 + 1e6), rtol=1e-12)
    np.testing.assert_allclose(diag[1:4], 3.0 * (1.0 + 1e-10) + 0.1**2, rtol=1e-12)  # a contact's: noise 0.1


def below_the_plate() -> np.ndarray:
    """Fingertip centres 2 cm under the plate, where it swept without a contact."""
    xs = np.arange(-0.02, 0.0201, 0.004)
    X, Y = np.meshgrid(xs, xs)
    return np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, -0.02)])


def test_a_free_space_point_is_observed_at_its_value_is_no_contact_and_drops_exactly() -> None:
    gp = plate_seen_from_above()
    n, P = gp.n_contacts, gp.positions_m
    x = np.array([[0.0, 0.0, -0.02]])
    before = gp.mean(x)
    assert before[0] < 0.0  # seen from one side, the plate's inside runs on below it
    gp.add_free_space(x, R_TIP)
    assert gp.mean(x)[0] == pytest.approx(R_TIP, abs=5e-4)
    assert gp.n_contacts == n and gp.n_free_space == 1
    np.testing.assert_array_equal(gp.positions_m, P)
    assert len(gp.normals) == n
    assert np.all(np.isfinite(gp.variance(x))) and gp.variance(x)[0] >= 0.0
    K = gp.observation_covariance()  # its diagonal: the contacts' noise, then the free-space point's
    np.testing.assert_allclose(gp.cholesky_factor() @ gp.cholesky_factor().T, K, rtol=0, atol=1e-12 * np.abs(K).max())
    gp.drop_free_space()  # the factor's leading block is the contacts' own: the same bits as before
    assert gp.n_free_space == 0
    np.testing.assert_array_equal(gp.mean(x), before)
    gp.add_free_space(x, R_TIP)
    gp.add_contact([0.0, 0.0, -0.004], -UP)  # a contact after free space ...
    assert gp.n_contacts == n + 1 and gp.n_free_space == 1
    with pytest.raises(EstimationError, match="between contacts"):  # ... keeps it
        gp.drop_free_space()
    with pytest.raises(EstimationError, match="free-space observations"):
        gp.truncate(1)


def test_free_space_is_refused_before_a_contact_and_for_a_bad_distance() -> None:
    with pytest.raises(EstimationError, match="needs a contact first"):
        GPIS(GPISConfig()).add_free_space([[0.0, 0.0, 0.0]], R_TIP)
    gp = plate_seen_from_above()
    factor = gp.cholesky_factor()
    for bad in (-0.001, float("nan")):
        with pytest.raises(EstimationError, match="finite and >= 0"):
            gp.add_free_space([[0.0, 0.0, -0.02]], bad)
    np.testing.assert_array_equal(gp.cholesky_factor(), factor)
    assert gp.n_free_space == 0


def test_enforce_lifts_the_mean_to_the_radius_where_it_was_broken_and_nowhere_else() -> None:
    gp = plate_seen_from_above()
    swept = below_the_plate()
    assert (gp.mean(swept) < R_TIP).all()
    added, refused = enforce(gp, swept, R_TIP, 0.004, rounds=6, tolerance_m=5e-4)
    assert not refused and 0 < len(added) <= len(swept) and len(set(added.tolist())) == len(added)
    assert gp.mean(swept).min() >= R_TIP - 5e-4 - 1e-9  # no swept centre breaks f >= r any more
    # above the plate the mean already says f >= r: nothing to add there
    above = swept + np.array([0.0, 0.0, 0.04])
    assert (gp.mean(above) >= R_TIP).all()
    assert len(enforce(gp, above, R_TIP, 0.004, rounds=6, tolerance_m=5e-4)[0]) == 0


def test_the_local_estimator_takes_no_free_space() -> None:
    gp = LocalGPIS(GPISConfig())
    gp.add_contact([0.0, 0.0, 0.0], UP)
    assert not gp.supports_free_space
    assert len(enforce(gp, below_the_plate(), R_TIP, 0.004, rounds=3, tolerance_m=5e-4)[0]) == 0
    with pytest.raises(EstimationError, match="no free-space observations"):
        gp.add_free_space([[0.0, 0.0, -0.02]], R_TIP)


def test_the_most_broken_point_of_each_voxel_is_kept() -> None:
    points = np.array([[0.001, 0.0, 0.0], [0.002, 0.0, 0.0], [0.011, 0.0, 0.0]])
    slack = np.array([-0.001, -0.003, -0.002])
    np.testing.assert_array_equal(most_broken_per_voxel(points, slack, 0.01), [1, 2])
    box = within_box(points, np.zeros(3), np.array([0.005, 1.0, 1.0]))
    np.testing.assert_array_equal(box, [True, True, False])


def test_swept_space_keeps_one_centre_per_voxel() -> None:
    swept = SweptSpace(0.002)
    for x in (0.0001, 0.0009, 0.0031):
        swept.add([x, 0.0, 0.0])
    assert len(swept) == 2
    np.testing.assert_allclose(swept.points_m()[:, 0], [0.0001, 0.0031])


def test_only_the_whole_object_mesh_keeps_the_swept_free_space() -> None:
    """With free_space the node reads pose and contacts and keeps the centres swept without a contact.
    The local mesh of a touch is the same as without; the whole-object mesh is not (the swept centres
    under the plate are no longer inside it), and after it the GP holds its contacts only."""
    assert set(SPEC.with_config(GPISNodeConfig()).inputs) == {"touches", "request"}
    config = GPISNodeConfig(free_space=True)
    assert set(SPEC.with_config(config).inputs) == {"touches", "request", "pose", "contacts"}
    meshes: dict[bool, list[SurfaceMesh]] = {}
    for free in (False, True):
        sent: list[Message] = []
        ctx = NodeContext("gpis", 0, lambda _, message, sent=sent: sent.append(message), {"surface": "surface/mesh"})
        node = GPISNode(GPISNodeConfig(free_space=free), ctx)
        node.on_contacts(no_contacts())  # no pose yet: nothing is known to be free
        for centre in below_the_plate():
            node.on_pose(pose(centre))
            node.on_contacts(no_contacts())
        assert len(node.session.swept) == len(below_the_plate())
        for x in (-0.02, 0.0, 0.02):
            for y in (-0.02, 0.0, 0.02):
                node.on_touches(touch([x, y, 0.0], UP))
        node.on_request(SurfaceRequest(stamp_ns=0, region="global", variance=False))
        meshes[free] = [m for m in sent if isinstance(m, SurfaceMesh)]
        exact = node.session.gp.estimator if isinstance(node.session.gp, AutoGPIS) else node.session.gp
        assert isinstance(exact, GPIS) and exact.n_free_space == 0 and exact.n_contacts == 9
        if free:
            assert ctx.counters["free_space_points"] > 0
            inside = exact.mean(below_the_plate()) < R_TIP
            assert inside.any()  # the contacts alone put the swept centres inside ...
    for without, with_free in zip(meshes[False][:-1], meshes[True][:-1], strict=True):
        np.testing.assert_array_equal(without.vertices_m, with_free.vertices_m)  # local meshes: the same
    whole_without, whole_with = meshes[False][-1], meshes[True][-1]
    assert whole_without.region == whole_with.region == "global"
    # ... the whole-object mesh with free space keeps them out: no estimated surface below them
    assert whole_without.vertices_m[:, 2].min() < -0.02 < whole_with.vertices_m[:, 2].min()


class _LineGP:
    """A stand-in estimator for ``enforce``: f(x) = x (the first coordinate), which free space does not
    move; records each round's observations and refuses the rounds listed in `refuse` (0-based)."""

    supports_free_space = True

    def __init__(self, refuse: tuple[int, ...] = ()) -> None:
        self.rounds: list[np.ndarray] = []
        self.refuse = refuse

    def mean(self, x: np.ndarray) -> np.ndarray:
        return np.asarray(x, dtype=np.float64)[:, 0].copy()

    def add_free_space(self, points_m: np.ndarray, distance_m: float) -> None:
        if len(self.rounds) in self.refuse:
            self.rounds.append(np.zeros((0, 3)))
            raise EstimationError("refused")
        self.rounds.append(np.array(points_m))


def test_enforce_observes_only_centres_below_the_radius_minus_the_tolerance_and_each_once() -> None:
    """f = x with r = 8 mm and tolerance 0.3 mm: slack x - r = -0.1, -0.5, +0.5, -8 mm, so only the
    second and fourth centres break f >= r - tolerance. The mean does not move, so later rounds find
    nothing new (each centre is observed at most once)."""
    swept = np.array([[0.0079, 0.0, 0.0], [0.0075, 0.0, 0.0], [0.0085, 0.0, 0.0], [0.0, 0.0, 0.0]])
    gp = _LineGP()
    added, refused = enforce(gp, swept, R_TIP, 0.001, rounds=4, tolerance_m=3e-4)  # type: ignore[arg-type]
    assert not refused and sorted(added.tolist()) == [1, 3] and len(gp.rounds) == 1
    assert sorted(gp.rounds[0][:, 0].tolist()) == [0.0, 0.0075]


def test_a_refused_round_stops_enforce_and_keeps_the_earlier_rounds() -> None:
    """Two broken centres in one 1 cm voxel: round 1 observes the more broken (x = 0), round 2 the
    other, and is refused: the first stays, the refusal is reported."""
    swept = np.array([[0.004, 0.0, 0.0], [0.0, 0.0, 0.0]])
    gp = _LineGP(refuse=(1,))
    added, refused = enforce(gp, swept, R_TIP, 0.01, rounds=6, tolerance_m=0.0)  # type: ignore[arg-type]
    assert refused and added.tolist() == [1] and len(gp.rounds) == 2
    added, refused = enforce(_LineGP(), swept, R_TIP, 0.01, rounds=6, tolerance_m=0.0)  # type: ignore[arg-type]
    assert not refused and added.tolist() == [1, 0]


def test_swept_voxels_are_floored_on_both_sides_of_zero() -> None:
    """floor(-0.05) = -1 and floor(0.05) = 0: centres 0.1 mm either side of 0 lie in different 2 mm voxels."""
    swept = SweptSpace(0.002)
    swept.add([-0.0001, 0.0, 0.0])
    swept.add([0.0001, 0.0, 0.0])
    swept.add([-0.0019, 0.0, 0.0])  # voxel -1 again
    np.testing.assert_allclose(swept.points_m()[:, 0], [-0.0001, 0.0001])
