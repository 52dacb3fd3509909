"""GPIS node: a touch it cannot use (beyond the sanity bounds, a normal that is no unit vector, or, with
grow_kernel off, too far from the contacts for the kernel) is refused before the GP changes; an object
larger than the kernel's R_m grows it; a request must name 'global'."""

from __future__ import annotations

import numpy as np
import pytest

from palpate.config import load
from palpate.errors import ConfigError, InputError
from palpate.messages.base import Message
from palpate.messages.schemas import SurfaceMesh, SurfaceRequest
from palpate.nodes.gpis import session as session_module
from palpate.nodes.gpis.core import GPIS, GPISConfig
from palpate.nodes.gpis.local import AutoGPIS
from palpate.nodes.gpis.node import GPISNode, _facts, _settle
from palpate.nodes.gpis.reach import holding, touch_reach
from palpate.nodes.gpis.session import GPISNodeConfig, GPISSession
from palpate.nodes.gpis.surface import grid_reach
from palpate.runtime.node import NodeContext
from tests.unit.node_messages import touch


def test_unusable_touches_leave_the_gp_unchanged() -> None:
    sent: list[Message] = []
    ctx = NodeContext("gpis", 0, lambda topic, message: sent.append(message), {"surface": "surface/mesh"})
    node = GPISNode(GPISNodeConfig(grow_kernel=False), ctx)
    node.on_touches(touch([0.0, 0.0, 0.03], [0.0, 0.0, 1.0]))
    exact = node.session.gp.estimator if isinstance(node.session.gp, AutoGPIS) else None
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
        assert node.session.gp.n_contacts == 1
        np.testing.assert_array_equal(exact.cholesky_factor(), factor)
    node.on_touches(touch([0.3, 0.0, 0.03], [1.0, 0.0, 0.0]))  # 0.3 m away still fits
    assert node.session.gp.n_contacts == 2 and len(sent) == 2
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


def test_an_object_larger_than_the_kernels_reach_grows_it_and_keeps_every_contact() -> None:
    """R_m = 0.5 m: a touch 0.45 m from the first needs 0.55 m (its local grid's far corner). The node
    rebuilds the GP with R_m doubled (1 m >= 1.25 x 0.55 m), from the same contacts and prior centre:
    the same estimate as a GP built with that R_m from the start. A touch 1 m away doubles it again."""
    sent: list[Message] = []
    ctx = NodeContext("gpis", 0, lambda topic, message: sent.append(message), {"surface": "surface/mesh"})
    node = GPISNode(GPISNodeConfig(), ctx)
    first, far = touch([0.0, 0.0, 0.03], [0.0, 0.0, 1.0]), touch([0.45, 0.0, 0.03], [1.0, 0.0, 0.0])
    node.on_touches(first)
    node.on_touches(far)
    assert node.session.gp.config.R_m == 1.0 and node.session.gp.n_contacts == 2 and len(sent) == 2
    assert ctx.counters["kernel_grown"] == 1 and ctx.metrics["kernel_R_m"] == 1.0
    direct = GPIS(GPISConfig(R_m=1.0), prior_centre_m=node.session.gp.prior_centre_m)
    direct.add_contact(first.position_m, first.normal)
    direct.add_contact(far.position_m, far.normal)
    x = np.random.default_rng(0).uniform(-0.05, 0.5, (50, 3))
    np.testing.assert_allclose(node.session.gp.mean(x), direct.mean(x), rtol=1e-9, atol=1e-12)
    node.on_touches(touch([0.0, 0.0, 0.03], [0.0, 0.0, 1.0]))  # near the first: no growth
    assert ctx.counters["kernel_grown"] == 1
    node.on_touches(touch([1.0, 0.0, 0.03], [1.0, 0.0, 0.0]))  # 1.07 m: doubled again
    assert node.session.gp.config.R_m == 2.0 and node.session.gp.n_contacts == 4 and ctx.counters["kernel_grown"] == 2


def test_the_whole_object_mesh_after_a_touch_is_held_at_the_touch_not_at_the_request() -> None:
    """The whole-object mesh with a 0.3 m margin spans 1.04 m around one touch (sqrt(3) 0.6 m) and 1.25 m
    around two 0.3 m apart: the first touch already grows R_m (twice, to 2 m >= 1.25 x 1.25 m), so that
    when the evaluator asks for that mesh does not change the GP the planner's meshes come from."""
    sent: list[Message] = []
    ctx = NodeContext("gpis", 0, lambda topic, message: sent.append(message), {"surface": "surface/mesh"})
    node = GPISNode(GPISNodeConfig(global_margin_m=0.3, global_resolution_m=0.01), ctx)
    node.on_touches(touch([0.0, 0.0, 0.03], [0.0, 0.0, 1.0]))
    assert node.session.gp.config.R_m == 2.0 and ctx.counters["kernel_grown"] == 1
    node.on_touches(touch([0.3, 0.0, 0.03], [1.0, 0.0, 0.0]))
    assert node.session.gp.config.R_m == 2.0 and ctx.counters["kernel_grown"] == 1 and node.session.gp.n_contacts == 2
    node.on_request(SurfaceRequest(stamp_ns=0, region="global", variance=False))
    assert node.session.gp.config.R_m == 2.0 and ctx.counters["kernel_grown"] == 1
    assert isinstance(sent[-1], SurfaceMesh) and sent[-1].region == "global" and len(sent[-1].vertices_m) > 0


def test_a_first_touch_whose_own_local_mesh_the_kernel_cannot_hold_grows_it_or_is_refused() -> None:
    """An outside audit: R_m = 5 cm (a 2 cm object's) against the +-6 cm local box, whose corners lie
    10.4 cm from the touch: the first touch was taken without growing, then its mesh failed, and the
    contact stayed. Now it grows the kernel; without growth it is refused with nothing changed."""
    gp = GPISConfig.for_object_size(0.02)
    grown = GPISSession(GPISNodeConfig(gp=gp))
    mesh = grown.touch([0.0, 0.0, 0.005], [0.0, 0.0, 1.0])
    assert grown.gp.n_contacts == 1 and grown.gp.config.R_m >= 1.25 * np.sqrt(3) * 0.06 and len(mesh.vertices) > 0
    assert grown.take_counts()["kernel_grown"] == 1
    fixed = GPISSession(GPISNodeConfig(gp=gp, grow_kernel=False))
    with pytest.raises(InputError, match=r"^position_m: the GPIS cannot add this touch \(its first\) with its local"):
        fixed.touch([0.0, 0.0, 0.005], [0.0, 0.0, 1.0])
    assert fixed.gp.n_contacts == 0 and fixed.gp.config.R_m == gp.R_m


def test_a_refused_touch_leaves_the_kernel_as_it_was_and_growth_stops_at_its_cap() -> None:
    """A touch far enough to grow R_m but with a normal that is no unit vector is refused before
    anything changes; one that would need R_m beyond kernel_radius_cap_m is refused as without growth."""
    ctx = NodeContext("gpis", 0, lambda topic, message: None, {"surface": "surface/mesh"})
    node = GPISNode(GPISNodeConfig(kernel_radius_cap_m=4.0), ctx)
    node.on_touches(touch([0.0, 0.0, 0.03], [0.0, 0.0, 1.0]))
    with pytest.raises(InputError, match=r"^normal: norm 2, not 1"):
        node.on_touches(touch([0.45, 0.0, 0.03], [2.0, 0.0, 0.0]))
    assert node.session.gp.config.R_m == 0.5 and node.session.gp.n_contacts == 1 and "kernel_grown" not in ctx.counters
    with pytest.raises(InputError, match=r"^position_m: the GPIS cannot add this touch to its 1 contacts"):
        node.on_touches(touch([5.0, 0.0, 0.03], [1.0, 0.0, 0.0]))  # needs R_m = 8 m > 4 m
    assert node.session.gp.config.R_m == 0.5 and node.session.gp.n_contacts == 1
    node.on_touches(touch([2.0, 0.0, 0.03], [1.0, 0.0, 0.0]))  # needs 4 m: grown
    assert node.session.gp.config.R_m == 4.0 and node.session.gp.n_contacts == 2


def test_a_local_resolution_no_touch_could_mesh_is_a_config_error() -> None:
    """An outside audit: local_resolution_m 1e-6 passed the launch, then every touch was refused as an
    input error and the run idled to its end with exit 0."""
    for step in (1e-6, 1e-300):
        with pytest.raises(ConfigError, match=r"local_resolution_m = .* makes a local grid of more than"):
            load(GPISNodeConfig, {"local_resolution_m": step})
    assert load(GPISNodeConfig, {"local_resolution_m": 0.0004}).local_resolution_m == 0.0004  # 301^3 nodes
    # too coarse: a 0.2 m step over the 0.12 m box left the planner targets at the contact, and the run stalled
    with pytest.raises(ConfigError, match=r"local_resolution_m = 0.2 leaves fewer than 4 cells .* at most 0.03 m"):
        load(GPISNodeConfig, {"local_resolution_m": 0.2})
    assert load(GPISNodeConfig, {"local_resolution_m": 0.03}).local_resolution_m == 0.03


def test_touch_reach_covers_the_local_grid_and_the_whole_object_box_with_the_touch() -> None:
    """One contact at 0, a touch at x = 0.3, half extent 1 cm, margin 5 cm: the local grid's far corner is
    sqrt(0.31^2 + 2 x 0.01^2) = 0.3103 m from the contact, the diagonal of the box of both grown by 5 cm
    sqrt(0.4^2 + 0.1^2 + 0.1^2) = 0.4243 m: the larger counts."""
    gp = GPIS(GPISConfig())
    # no contact yet: the touch's own grid corner (sqrt(3) cm) or the diagonal of its point grown by 5 cm
    assert touch_reach(gp, [0.3, 0.0, 0.0], 0.01, 0.05) == pytest.approx(np.sqrt(3) * 0.1, rel=1e-12)
    assert touch_reach(gp, [0.3, 0.0, 0.0], 0.01, 0.0) == pytest.approx(np.sqrt(3) * 0.01, rel=1e-12)
    gp.add_contact([0.0, 0.0, 0.0], [0.0, 0.0, 1.0])
    assert touch_reach(gp, [0.3, 0.0, 0.0], 0.01, 0.05) == pytest.approx(np.sqrt(0.18), rel=1e-12)
    assert touch_reach(gp, [0.3, 0.0, 0.0], 0.01, 0.0) == pytest.approx(np.sqrt(0.31**2 + 2e-4), rel=1e-12)
    assert grid_reach(np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]]), np.zeros(3), 0.01) == pytest.approx(
        np.sqrt(0.11**2 + 2e-4), rel=1e-12
    )  # the farther contact's corner, not the nearer's


def test_holding_doubles_r_until_it_has_the_headroom() -> None:
    """R_m = 0.5 m holds 0.45 m as it is; 0.9 m needs R_m >= 1.25 x 0.9 = 1.125 m: 0.5 -> 1 -> 2 m
    (1 m would hold 0.9 m, but without the headroom); beyond the cap the GP is returned unchanged."""
    gp = GPIS(GPISConfig(), prior_centre_m=[0.0, 0.0, -0.01])
    gp.add_contact([0.0, 0.0, 0.0], [0.0, 0.0, 1.0])
    assert holding(gp, 0.45, 8.0) is gp
    grown = holding(gp, 0.9, 8.0)
    assert grown.config.R_m == 2.0 and grown.n_contacts == 1
    np.testing.assert_array_equal(grown.prior_centre_m, [0.0, 0.0, -0.01])
    assert holding(gp, 0.9, 1.5) is gp


def test_the_session_counts_a_finer_local_mesh_and_gives_the_variance_where_configured() -> None:
    """The needle of test_surface: its second touch is meshed on a 2.5 mm grid (counted); a sphere
    touch is not. vertex_variance "all" gives every vertex a variance, "candidates" some."""
    P = np.array([[0.000354, -0.000354, 0.030298], [-0.000462, 0.000191, 0.028963]])
    N = np.array([[0.688312, -0.725415, 0.0], [-0.856953, 0.515394, 0.0]])
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    needle = GPISSession(GPISNodeConfig(local_half_extent_m=0.05))
    needle.touch(P[0], N[0])
    assert needle.take_counts() == {}
    needle.touch(P[1], N[1])
    assert needle.take_counts() == {"local_mesh_refined": 1}
    rng = np.random.default_rng(3)
    u = rng.standard_normal((30, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    meshes = {}
    for where in ("all", "candidates"):
        session = GPISSession(GPISNodeConfig(local_half_extent_m=0.05, vertex_variance=where))
        session.gp.add_contacts(0.04 * u[:-1], u[:-1])
        meshes[where] = session.touch(0.04 * u[-1], u[-1])
        assert session.take_counts() == {}
    everywhere, candidates = meshes["all"], meshes["candidates"]
    np.testing.assert_array_equal(everywhere.variance_vertices, np.arange(len(everywhere.vertices)))
    assert 0 < len(candidates.variance_vertices) < len(candidates.vertices) / 2


def test_the_whole_object_mesh_enforces_the_swept_centres_in_its_box_and_counts(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The box of contacts at x = 0 and 2 cm grown by 3 cm reaches z = -3 cm: the centre swept at
    z = -2 cm is enforced, the one at -5 cm not. The counters take what ``enforce`` reports."""
    session = GPISSession(GPISNodeConfig(free_space=True, global_margin_m=0.03))
    session.gp.add_contacts(np.array([[0.0, 0.0, 0.0], [0.02, 0.0, 0.0]]), np.tile([0.0, 0.0, 1.0], (2, 1)))
    session.no_contact()  # no pose yet
    for centre in ([0.01, 0.0, -0.02], [0.01, 0.0, -0.05]):
        session.pose(centre)
        session.no_contact()
    seen: list[np.ndarray] = []

    def fake_enforce(gp: object, centres: np.ndarray, *args: object) -> tuple[np.ndarray, bool]:
        seen.append(centres.copy())
        return np.arange(3), True

    monkeypatch.setattr(session_module, "enforce", fake_enforce)
    session.whole(False)
    assert len(seen) == 1
    np.testing.assert_array_equal(seen[0], [[0.01, 0.0, -0.02]])
    assert session.take_counts() == {"free_space_points": 3, "free_space_refused": 1}
    assert session.take_counts() == {}


def test_the_node_publishes_the_contact_count_and_the_kernel_range_only_once_grown() -> None:
    ctx = NodeContext("gpis", 0, lambda topic, message: None, {"surface": "surface/mesh"})
    node = GPISNode(GPISNodeConfig(), ctx)
    node.on_touches(touch([0.0, 0.0, 0.03], [0.0, 0.0, 1.0]))
    assert ctx.metrics["contacts"] == 1.0 and "kernel_R_m" not in ctx.metrics


def test_the_variance_facts_and_the_auto_setting() -> None:
    """Vertex variance "auto" and "candidates" state the candidates' step; "auto" settles on what the
    planner states."""
    for where, step in (("auto", True), ("candidates", True), ("all", False), ("none", False)):
        facts = _facts(GPISNodeConfig(vertex_variance=where, variance_step_m=0.007))
        assert facts["surface:candidate_variance"][0] == ("not given" if where == "none" else "given")
        assert facts.get("surface:candidate_step_m") == ((0.007, ("variance_step_m",)) if step else None)
    auto = GPISNodeConfig(vertex_variance="auto")
    assert _settle(auto, lambda key: ["given"]) == {("vertex_variance",): "candidates"}
    assert _settle(auto, lambda key: []) == {("vertex_variance",): "none"}
    assert _settle(GPISNodeConfig(vertex_variance="all"), lambda key: ["given"]) == {}


def test_growth_allows_for_the_local_grid_overhanging_its_half_extent() -> None:
    """At 7 mm steps a 0.12 m box takes 19 nodes: the grid's half extent is 63 mm, not 60. A touch
    0.431 m from the first needs sqrt(0.494^2 + 2 x 0.063^2) = 0.502 m > R_m = 0.5 m (it would fit at
    60 mm: 0.498 m): the session grows the kernel for it instead of letting the mesh refuse it."""
    session = GPISSession(GPISNodeConfig(local_resolution_m=0.007, global_margin_m=0.0, global_resolution_m=0.001))
    session.touch([0.0, 0.0, 0.03], [0.0, 0.0, 1.0])
    session.touch([0.431, 0.0, 0.03], [1.0, 0.0, 0.0])
    assert session.gp.config.R_m == 1.0 and session.gp.n_contacts == 2
    assert session.take_counts() == {"kernel_grown": 1}


def test_a_whole_object_mesh_whose_grid_would_be_too_large_is_made_coarser_and_said_once(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """An outside audit: global_resolution_m = 0.1 mm (as a 1.5 m object at 3 mm) had every whole-object
    request refused, and the run ended 'complete' with every accuracy score null."""
    from palpate.nodes.gpis import surface

    assert surface.fitting_resolution([0.1, 0.1, 0.1], 0.003) == 0.003  # 35^3 nodes fit
    step = surface.fitting_resolution([1.56, 1.56, 1.56], 0.003)  # a 1.5 m object: 521^3 nodes do not
    assert 1.0 < step / 0.003 < 1.5 and surface.axis_nodes(1.56, step) ** 3 <= surface.MAX_GRID_NODES
    assert surface.axis_nodes(1.56, step / 1.02) ** 3 > surface.MAX_GRID_NODES  # no coarser than needed
    sent: list[Message] = []
    ctx = NodeContext("gpis", 0, lambda topic, message: sent.append(message), {"surface": "surface/mesh"})
    node = GPISNode(GPISNodeConfig(), ctx)
    for normal in np.eye(3):
        node.on_touches(touch(0.02 * normal, normal))
    monkeypatch.setattr(surface, "MAX_GRID_NODES", 20**3)  # the whole object's 29^3 nodes do not fit
    with caplog.at_level("WARNING"):
        for _ in range(2):
            node.on_request(SurfaceRequest(stamp_ns=0, region="global", variance=False))
    assert isinstance(sent[-1], SurfaceMesh) and sent[-1].region == "global" and len(sent[-1].faces) > 0
    assert node.session.whole_resolution_m > 0.003
    said = [r.getMessage() for r in caplog.records if "whole-object mesh" in r.getMessage()]
    assert len(said) == 1 and "global_resolution_m = 0.003 m would exceed 8000 grid nodes" in said[0]


def test_whole_mesh_options_the_local_experts_drop_are_said_once(caplog: pytest.LogCaptureFixture) -> None:
    """An outside walkthrough: free_space and whole_prior hull stopped applying past 1500 contacts (the local
    experts) and the figures were those of a run without them, without a word."""
    sent: list[Message] = []
    ctx = NodeContext("gpis", 0, lambda topic, message: sent.append(message), {"surface": "surface/mesh"})
    config = load(GPISNodeConfig, {"free_space": True, "whole_prior": "hull", "gp": {"estimator": "local"}})
    node = GPISNode(config, ctx)
    rng = np.random.default_rng(0)
    for normal in rng.normal(size=(8, 3)):
        normal /= np.linalg.norm(normal)
        node.on_touches(touch(0.02 * normal, normal))
    with caplog.at_level("WARNING"):
        for _ in range(2):
            node.on_request(SurfaceRequest(stamp_ns=0, region="global", variance=False))
    said = [r.getMessage() for r in caplog.records if "is not applied" in r.getMessage()]
    assert len(said) == 2 and "whole_prior: hull" in said[0] and "free_space is not applied" in said[1]
    assert isinstance(sent[-1], SurfaceMesh) and sent[-1].region == "global"
