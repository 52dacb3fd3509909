"""Next-best-touch selection (paper 002, Sections 2.3-2.4, Eqs. 7-12, Algorithm 2).

The planner sees the estimated surface only as arrays: candidate points on the surface mesh, their
outward unit normals and the GP variance there. ``sample_candidates`` thins the mesh near the last
contact; ``Planner.select`` rates the candidates with the configured strategy and picks one.
``TouchPlanner`` is the planner node's whole decision: it remembers the contacts, plans once per
contact when the local surface that includes it arrives, and drops targets it cannot usefully reach
(admissibility rules not in the paper, see PlannerConfig).

Conventions: metres; the fingertip's local z axis ``R_z`` is the direction it pokes (it faces a surface
with outward normal n when ``R_z = -n``); ``v_n`` is the unit velocity just before the last contact.

Choices where the paper disagrees with itself (both configurable):
- Psi2 measures the Eq. 15 curve, beta = |r - s| / 3 (``psi2_control_scale = 1/3``). Algorithm 2
  line 4 writes the control points without the 1/3, but Eq. 8 defines Psi2 as the length of "the
  planned path", and the path the controller actually follows is Eq. 15. With scale 1 the control
  points sit three times further out, the curve loops, and Psi2 no longer measures the executed cost.
- Psi4 = exp(-2 sin^2(alpha/2) / sigma_alpha^2) (Eq. 11), decreasing in the rotation alpha the
  fingertip needs to face the target, as goal (4) of Section 2.4 asks ("minimize the rotation").
  Here alpha is the rotation itself: the angle between the poking axis R_z and the inward target
  normal -s_n, so 2 sin^2(alpha/2) = 1 - cos(alpha) = 1 + R_z . s_n (Eq. 11's arccos(R_z, s_n)
  is this angle when R_z points out of the fingertip, "aligned with the surface normal").
  Algorithm 2 line 5 writes 1 - exp(...): with alpha the rotation that rewards turning. It only
  penalises rotation if alpha is measured to the opposite axis (alpha = pi - rotation), and even
  then it is another function (1 - e^-2 = 0.86 for no turn, 0 for a half turn, against Eq. 11's
  1 and e^-2), so Eq. 11 is taken as the definition.
- Psi2 = 1 / max(Len, min_path_m): a target at the fingertip (closer than its radius) has a path of
  length ~0 and would otherwise score infinity.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, replace
from functools import cached_property
from itertools import permutations
from typing import Annotated, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist

from palpate.config import NonNegativeFloat, PositiveFloat, PositiveInt, Range, Validated
from palpate.errors import InputError, PlanningError
from palpate.geometry.bezier import approach_curve, bezier_length, bezier_point
from palpate.geometry.rotations import quat_to_matrix
from palpate.geometry.thinning import thin_near
from palpate.inputs import (
    MAX_COORDINATE_M,
    bounded,
    coordinates,
    unit_or_zero,
    unit_or_zero_rows,
    vertex_subset,
)
from palpate.messages.schemas import MAX_MISS_DISTANCE_M

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
Strategy = Literal["igef", "gpv", "random", "area", "tour"]


@dataclass(frozen=True, kw_only=True)
class PlannerConfig(Validated):
    """Planner parameters; defaults are the paper's YCB settings (Section 2.4 and 2.6)."""

    strategy: Strategy = "igef"
    sigma1_m: PositiveFloat = 0.02  # sigma_1 of Eq. 7
    mu3_m: NonNegativeFloat = 0.02  # mu_3 of Eq. 10
    sigma3_m: PositiveFloat = 0.02  # sigma_3 of Eq. 10
    sigma_alpha: PositiveFloat = 1.0  # sigma_alpha of Eq. 11
    #: Candidate sampling on the estimated surface: step 0.5 cm, up to 5 cm from the last contact.
    candidate_step_m: PositiveFloat = 0.005
    candidate_radius_m: PositiveFloat = 0.05
    #: GP-V's maximum target distance from the last contact (Section 2.6: 6 cm).
    gpv_radius_m: PositiveFloat = 0.06
    #: beta = scale * |r - s| in the Psi2 path (1/3 = Eq. 15; 1 = Algorithm 2 line 4 literally).
    psi2_control_scale: PositiveFloat = 1.0 / 3.0
    #: Floor on the Psi2 path length, metres (targets closer than the fingertip radius).
    min_path_m: PositiveFloat = 1e-3
    #: Not in the paper, for every strategy alike: drop targets whose executed Eq. 15 curve brings the
    #: fingertip into the estimated object before the end (see ``curves_clear``). Without it GP-V picks
    #: the far side of small objects, the curve runs through them, and the fingertip touches again next
    #: to its start, often with its back (measured: 400 contacts, 3 % coverage on the YCB golf ball).
    check_curves: bool = True
    #: How far the fingertip sphere may dip into the estimated surface along a curve, metres (the
    #: estimate's and the nearest-vertex distance's error): the centre keeps tip_radius_m - this.
    curve_margin_m: NonNegativeFloat = 0.001
    #: Points sampled on each candidate curve for that check (tau in (0, 1)).
    curve_samples: PositiveInt = 16
    #: Not in the paper, for every strategy alike: a target whose fingertip centre (t_p + radius t_n) lies
    #: closer than this to the fingertip centre now is not admissible, metres. Such an action barely
    #: moves the fingertip: where the estimate rounds a concave corner (the floor of a cup meeting its
    #: wall) IGEF's shortest path picked a target the fingertip already touched, and the same contact
    #: repeated hundreds of times (measured on the YCB cups). 6 mm is the coverage radius.
    min_hop_m: NonNegativeFloat = 0.006
    #: Not in the paper, for every strategy alike: a target whose touch landed further than
    #: ``unreached_miss_m`` from it (the curve hit the object on the way, or the estimate was wrong there)
    #: is remembered, and candidates within ``unreached_radius_m`` of a remembered target are not
    #: admissible. Without it a strategy re-picks a target it cannot reach (GP-V: its variance stays high
    #: because no contact lands there) and touches the same spot again and again; IGEF's targets in the
    #: concave corner where a cup's floor meets its wall, which the 8 mm fingertip cannot reach, drew
    #: 500 touches 9.5 mm away on 13 spots (measured on YCB 065-i: coverage stuck at 26 %; with 5 mm it
    #: reached 80 % in 387 contacts). 0 disables it.
    unreached_radius_m: NonNegativeFloat = 0.006
    unreached_miss_m: NonNegativeFloat = 0.005
    #: Fingertip radius, metres (the controller's tip_radius_m): the curves guide the fingertip centre.
    tip_radius_m: NonNegativeFloat = 0.008
    #: Area strategy (not in the paper, see ``area_scores``): the radius one touch explores
    #: (the evaluation's 6 mm), and the fixed cost of a touch in metres of travel, which makes a touch
    #: that explores more worth a longer path.
    area_radius_m: PositiveFloat = 0.006
    area_touch_cost_m: NonNegativeFloat = 0.02
    #: Extra weight of an unexplored patch per explored fraction of its surroundings (2 rho): holes and
    #: the rim of the explored region first, so that no patch is left for a long trip back.
    area_hole_weight: NonNegativeFloat = 2.0
    #: Experimental: weight kappa of the GP variance in the area strategy's gain, G(s) (1 + kappa
    #: var(s) / max var), so that among equal new areas the least known is touched first; 0 (default)
    #: leaves the variance out (and the strategy then needs none from the GPIS node).
    area_variance_weight: NonNegativeFloat = 0.0
    #: Tour strategy (not in the paper, see ``tour_plan``): candidates up to ``tour_radius_m`` from the
    #: last contact (GP-V's 6 cm, where the GPIS node gives the variance); a tour through at most
    #: ``tour_sites`` of the ``tour_pool`` best candidates is planned and its first site touched.
    tour_radius_m: PositiveFloat = 0.06
    tour_sites: PositiveInt = 4
    tour_pool: PositiveInt = 32
    #: Fixed cost of a touch on the tour, metres of travel (as area_touch_cost_m).
    tour_touch_cost_m: NonNegativeFloat = 0.02
    #: Patch weight w(q) = 1 + beta e(q) + gamma min(d(q) / D, 1): beta as area_hole_weight; gamma the
    #: weight of the patch's distance d(q) from every contact (how far the GP must extrapolate there),
    #: saturating at D = 3 cm (5 coverage radii). gamma 3 and D 3 cm against the first 1 and 2 cm: the
    #: same travel on the 30 shared objects, a better whole estimate (docs/exploration.md).
    tour_hole_weight: NonNegativeFloat = 2.0
    tour_far_weight: NonNegativeFloat = 3.0
    tour_far_m: PositiveFloat = 0.03
    #: Weight kappa of the GP variance in the patch weight, w(q) (1 + kappa var(q) / max var): the GP's
    #: own doubt, where its estimate bulges away from the contacts. 0 (default): the GPIS node computes
    #: no variance for the tour; kappa 1 with a 3 cm touch cost buys a better whole estimate with 20 %
    #: more travel (docs/exploration.md compares the settings on the 30 shared objects).
    tour_variance_weight: NonNegativeFloat = 0.0
    #: Not in the paper: reach a target by sliding the fingertip along the surface from the last contact
    #: (``TouchTarget.slide``; the controller keeps it in contact and steers it to the target) instead of
    #: lifting it along the Eq. 15 curve, when the target lies within this distance of the last contact
    #: and its normal within ``slide_max_angle_deg`` of that contact's, metres. ``slide_max_m`` holds
    #: for every strategy (0, the default: the paper's strategies lift); ``tour_slide_max_m`` for the
    #: tour alone, which slides to any target in its view (6 cm) by default. 60 degrees against 45 and
    #: 90: the least whole-estimate error for the same travel on the 30 shared objects
    #: (docs/exploration.md, "Slides").
    slide_max_m: NonNegativeFloat = 0.0
    tour_slide_max_m: NonNegativeFloat = 0.06
    slide_max_angle_deg: Annotated[float, Range(ge=0.0, le=90.0)] = 60.0
    #: Not in the paper: how far past its target the fingertip may go without a contact before Algorithm
    #: 1's recovery (Delta_m, sent as ``TouchTarget.miss_distance_m``), metres, at most
    #: MAX_MISS_DISTANCE_M; 0 sends 0, which leaves it to the controller's own Delta_m (its
    #: ``miss_distance_m``, 1 cm). ``miss_distance_m`` holds for every strategy (0, the default: the
    #: paper's strategies keep the controller's), ``tour_miss_distance_m`` for the tour when not 0: 3 cm,
    #: so that a touch aimed at surface the estimate invents (the GP closes a cup's unexplored inside
    #: with a false floor) goes on to the true surface behind it, where 1 cm ends in the recovery and a
    #: touch where the fingertip left (docs/exploration.md, "A longer reach past a missed target").
    miss_distance_m: Annotated[float, Range(ge=0.0, le=MAX_MISS_DISTANCE_M)] = 0.0
    tour_miss_distance_m: Annotated[float, Range(ge=0.0, le=MAX_MISS_DISTANCE_M)] = 0.03

    @property
    def slide_reach_m(self) -> float:
        """How far from the last contact this strategy slides to a target (0: it never slides)."""
        return max(self.slide_max_m, self.tour_slide_max_m if self.strategy == "tour" else 0.0)

    @property
    def target_miss_distance_m(self) -> float:
        """Delta_m this strategy asks of the controller with each target (0: the controller's own)."""
        return (
            self.tour_miss_distance_m
            if self.strategy == "tour" and self.tour_miss_distance_m > 0.0
            else self.miss_distance_m
        )

    @property
    def uses_variance(self) -> bool:
        """Whether the strategy rates candidates by the GP variance (GP-V; area or tour with a variance
        weight)."""
        return (
            self.strategy == "gpv"
            or (self.strategy == "area" and self.area_variance_weight > 0.0)
            or (self.strategy == "tour" and self.tour_variance_weight > 0.0)
        )

    @property
    def radius_m(self) -> float:
        """Largest target distance from the last contact for the configured strategy."""
        if self.strategy == "gpv":
            return self.gpv_radius_m
        if self.strategy == "tour":
            return self.tour_radius_m
        return self.candidate_radius_m


@dataclass(frozen=True)
class Candidates:
    """Thinned surface points: positions (m, 3) metres, unit normals (m, 3), variance (m,), and the
    row of each in the arrays they were sampled from (m,)."""

    points_m: FloatArray
    normals: FloatArray
    variance: FloatArray
    indices: IntArray


@dataclass(frozen=True)
class Selection:
    """The chosen touch target.

    index: row in the candidate arrays; target_m, normal: t_p (m) and outward unit t_n; predicted
    contact: where the estimated surface says the touch lands (the target itself); score: its rating;
    scores: every candidate's rating (m,), 0 outside the strategy's radius; psi: IGEF's factors
    Psi1..Psi4 per candidate (m, 4), or None for the other strategies.
    """

    index: int
    target_m: FloatArray
    normal: FloatArray
    predicted_contact_m: FloatArray
    score: float
    scores: FloatArray
    psi: FloatArray | None = None
    #: Reach it by sliding along the surface from the last contact (PlannerConfig.slide_reach_m and
    #: slide_max_angle_deg decide).
    slide: bool = False


def _points(name: str, value: ArrayLike) -> FloatArray:
    a = np.asarray(value, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3:
        raise PlanningError(f"{name} must have shape (m, 3), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise PlanningError(f"{name} holds NaN or infinity in {int((~np.isfinite(a)).any(1).sum())} rows")
    return a


def _vector(name: str, value: ArrayLike) -> FloatArray:
    a = np.asarray(value, dtype=np.float64)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise PlanningError(f"{name} must be a finite 3-vector, got {value!r}")
    return a


def _unit_rows(name: str, value: ArrayLike) -> FloatArray:
    a = _points(name, value)
    norm = np.linalg.norm(a, axis=1, keepdims=True)
    bad = norm[:, 0] < 1e-12
    if np.any(bad):
        raise PlanningError(
            f"{name}: {int(bad.sum())} normals have zero length (first at row {int(np.argmax(bad))}); "
            "the surface estimate must give a unit normal for every candidate"
        )
    return a / norm


def sample_candidates(
    vertices: ArrayLike,
    normals: ArrayLike,
    variance: ArrayLike,
    last_contact: ArrayLike,
    step_m: float = 0.005,
    radius_m: float = 0.05,
) -> Candidates:
    """Thin surface points to about ``step_m`` spacing within ``radius_m`` of the last contact.

    Section 2.4: "the estimated surface S is sampled, starting from the last contact position" with
    a 0.5 cm step up to 5 cm. ``thinning.thin_near``: a voxel grid of edge ``step_m`` centred on the
    last contact keeps, per occupied voxel, the surface point nearest the voxel centre (a real mesh
    point, so its normal and variance stay exact). vertices, normals: (k, 3); variance: (k,);
    last_contact: (3,).
    Returns possibly zero candidates (the caller decides what an empty surface means).
    """
    V = _points("vertices", vertices)
    N = np.asarray(normals, dtype=np.float64)
    Q = np.asarray(variance, dtype=np.float64)
    c = _vector("last_contact", last_contact)
    if N.shape != V.shape or Q.shape != (V.shape[0],):
        raise PlanningError(f"normals {N.shape} and variance {Q.shape} must match vertices {V.shape}")
    if not (step_m > 0.0 and radius_m > 0.0):
        raise PlanningError(f"step_m and radius_m must be > 0, got {step_m!r}, {radius_m!r}")
    keep = thin_near(V, c, step_m, radius_m)
    return Candidates(
        points_m=V[keep].copy(),
        normals=N[keep].copy(),
        variance=Q[keep].copy(),
        indices=keep,
    )


def path_length(r: FloatArray, v_n: FloatArray, s_p: FloatArray, s_n: FloatArray, config: PlannerConfig) -> FloatArray:
    """Eqs. 8-9: the length (m,) of the Eq. 15 curve from r (3,), leaving along -v_n (3,), to each
    candidate s_p (m, 3) against its normal s_n (m, 3), with beta = psi2_control_scale |r - s_p|."""
    return bezier_length(approach_curve(r, v_n, s_p, s_n, scale=config.psi2_control_scale))


def rotation_factor(s_n: FloatArray, R_z: FloatArray, config: PlannerConfig) -> FloatArray:
    """Eq. 11: Psi4(s) = exp(-2 sin^2(alpha/2) / sigma_alpha^2) per candidate normal s_n (m, 3), with
    alpha = angle(R_z, -s_n), so 2 sin^2(alpha/2) = 1 - cos(alpha) = 1 + R_z . s_n."""
    return np.exp(-(1.0 + s_n @ R_z) / config.sigma_alpha**2)


def igef_terms(
    candidates_m: FloatArray,
    normals: FloatArray,
    contacts_m: FloatArray,
    r: FloatArray,
    v_n: FloatArray,
    R_z: FloatArray,
    config: PlannerConfig,
) -> FloatArray:
    """IGEF factors Psi1..Psi4 for every candidate (Algorithm 2), shape (m, 4).

    candidates_m, normals (unit): (m, 3); contacts_m: (n, 3), n >= 1; r: fingertip position (3,);
    v_n: unit velocity before the last contact (3,); R_z: unit poking axis of the fingertip (3,).
    """
    d = cdist(candidates_m, contacts_m)  # |s_p - c_p|, (m, n)
    # Eq. 7, Alg. 2 line 2: Psi1(s) = min_c 1 - exp(-|s_p - c_p|^2 / sigma1^2) (monotone in |s - c|)
    psi1 = 1.0 - np.exp(-(d.min(axis=1) ** 2) / config.sigma1_m**2)
    # Eqs. 8-9, Alg. 2 line 4: Psi2(s) = 1 / Len(bezier(r, r - beta v_n, s_p + beta s_n, s_p))
    psi2 = 1.0 / np.maximum(path_length(r, v_n, candidates_m, normals, config), config.min_path_m)
    # Eq. 10, Alg. 2 line 3: Psi3(s) = sum_c exp(-(|s - c| - mu3)^2 / sigma3^2), in place on d (m x n)
    d -= config.mu3_m
    d *= 1.0 / config.sigma3_m
    np.square(d, out=d)
    np.negative(d, out=d)
    np.exp(d, out=d)
    psi3 = d.sum(axis=1)
    psi4 = rotation_factor(normals, R_z, config)  # Eq. 11
    return np.stack([psi1, psi2, psi3, psi4], axis=1)


def hole_weights(
    tree: cKDTree, candidates_m: FloatArray, is_unexplored: NDArray[np.bool_], rho: float, beta: float
) -> FloatArray:
    """beta e(q) of every unexplored candidate q (u,), e(q) the explored share of the candidates within
    2 rho of q: holes and the rim of the explored region weigh more (area and tour strategies).
    tree: cKDTree of candidates_m (m, 3); is_unexplored (m,) with explored and unexplored candidates."""
    unexplored = candidates_m[is_unexplored]
    around = tree.query_ball_point(unexplored, 2.0 * rho, return_length=True)
    explored = cKDTree(candidates_m[~is_unexplored])
    explored_around = explored.query_ball_point(unexplored, 2.0 * rho, return_length=True)
    return np.asarray(beta * explored_around / np.maximum(around, 1), dtype=np.float64)


def area_scores(
    candidates_m: FloatArray,
    normals: FloatArray,
    contacts_m: FloatArray,
    r: FloatArray,
    v_n: FloatArray,
    R_z: FloatArray,
    config: PlannerConfig,
    variance: FloatArray | None = None,
) -> FloatArray:
    """Area strategy (not in the paper): new explored area per unit of travel, for every candidate (m,).

    The candidates, thinned to about ``candidate_step_m`` apart on the estimated surface, stand for
    equal patches of it. A patch is explored when a contact lies within the coverage radius rho of it.
    A touch at s explores the unexplored patches within rho of s:

        G(s) = sum_{q unexplored, |q - s| <= rho} w(q),  w(q) = 1 + beta * (explored share within 2 rho of q)
        score(s) = G(s) * Psi4(s) / (Len(s) + L0)

    with Len(s) the Eq. 15 path (IGEF's Psi2 curve), Psi4 IGEF's rotation factor (Eq. 11) and L0 the
    fixed cost of a touch. beta (``area_hole_weight``) favours the holes and the rim of the explored
    region, so that no unexplored patch is left behind for a long trip back. When no candidate explores
    anything (the local surface is covered), the score is the distance to the nearest contact per unit
    of travel, which leads out of the covered region.
    With ``area_variance_weight`` kappa > 0 and the GP variance (m,) at the candidates, the gain is
    G(s) (1 + kappa var(s) / max var): among equal new areas, the least known first.
    candidates_m, normals (unit): (m, 3); contacts_m: (n, 3); r, v_n, R_z as in igef_terms.
    """
    rho = config.area_radius_m
    explored_by, _ = cKDTree(contacts_m).query(candidates_m)  # distance to the nearest contact (m,)
    is_unexplored = explored_by > rho
    unexplored = candidates_m[is_unexplored]
    cost = path_length(r, v_n, candidates_m, normals, config) + config.area_touch_cost_m
    psi4 = rotation_factor(normals, R_z, config)  # Eq. 11
    if len(unexplored):
        candidate_tree = cKDTree(candidates_m)
        weight = np.ones(len(unexplored))
        if config.area_hole_weight > 0.0 and len(unexplored) < len(candidates_m):
            weight += hole_weights(candidate_tree, candidates_m, is_unexplored, rho, config.area_hole_weight)
        pairs = candidate_tree.sparse_distance_matrix(cKDTree(unexplored), rho, output_type="ndarray")
        gain = np.bincount(pairs["i"], weights=weight[pairs["j"]], minlength=len(candidates_m))
        if config.area_variance_weight > 0.0 and variance is not None and variance.max() > 0.0:
            gain *= 1.0 + config.area_variance_weight * variance / variance.max()
        if gain.max() > 0.0:
            return np.asarray(gain * psi4 / cost, dtype=np.float64)
    return np.asarray(explored_by * psi4 / cost, dtype=np.float64)


#: A tour site lies at least this fraction of the coverage radius rho from every contact (``tour_plan``).
SITE_AWAY = 0.5


@dataclass(frozen=True)
class Tour:
    """A planned tour: the candidate rows of its sites in visiting order (k,), the new (weighted) area
    each site explores after the sites before it (k,), its travel in metres (touch costs included),
    and every candidate's rating (m,), the tour's sites first in tour order (see ``tour_plan``)."""

    sites: IntArray
    gains: FloatArray
    cost_m: float
    scores: FloatArray


def patch_weights(
    candidates_m: FloatArray,
    explored_by: FloatArray,
    config: PlannerConfig,
    variance: FloatArray | None = None,
    tree: cKDTree | None = None,
) -> FloatArray:
    """The tour's weight of every candidate patch (m,), 0 for explored ones (nearest contact within rho):

        w(q) = (1 + beta e(q) + gamma min(d(q) / D, 1)) (1 + kappa var(q) / max var)

    e(q): explored share of the candidates within 2 rho of q (holes and the rim first, as in area);
    d(q) = explored_by (m,): distance from q to the nearest contact (the GP extrapolates over distant
    patches, so those count more: touches spread); kappa var: optional GP variance (m,) term;
    tree: the candidates' cKDTree when the caller has one.
    """
    rho = config.area_radius_m
    is_unexplored = explored_by > rho
    w = np.zeros(len(candidates_m))
    if not is_unexplored.any():
        return w
    base = 1.0 + config.tour_far_weight * np.minimum(explored_by[is_unexplored] / config.tour_far_m, 1.0)
    if config.tour_hole_weight > 0.0 and not is_unexplored.all():
        tree = cKDTree(candidates_m) if tree is None else tree
        base += hole_weights(tree, candidates_m, is_unexplored, rho, config.tour_hole_weight)
    w[is_unexplored] = base
    if config.tour_variance_weight > 0.0 and variance is not None and variance.max() > 0.0:
        w *= 1.0 + config.tour_variance_weight * variance / variance.max()
    return w


def best_order(start_cost: FloatArray, hop_cost: FloatArray) -> IntArray:
    """The cheapest visiting order of k sites (all k! orders tried for k <= 7; above, the given order is
    kept): start_cost (k,) from the fingertip to each site, hop_cost (k, k) from site i to site j.
    Returns the order (k,); ties go to the lexicographically first order."""
    k = len(start_cost)
    if k <= 1 or k > 7:
        return np.arange(k)
    orders = np.array(list(permutations(range(k))))  # (k!, k), lexicographic
    cost = start_cost[orders[:, 0]] + hop_cost[orders[:, :-1], orders[:, 1:]].sum(axis=1)
    return np.asarray(orders[int(np.argmin(cost))], dtype=np.int64)


def greedy_insertion(
    cover: FloatArray, w: FloatArray, psi4: FloatArray, start: FloatArray, hop: FloatArray, config: PlannerConfig
) -> list[int]:
    """The tour of ``tour_plan`` by greedy insertion: pool rows in visiting order.

    cover (P, m): pool site a explores patch q; w (m,): patch weights; psi4 (P,): the sites' rotation
    factors; start (P,): Len(r -> s_a); hop (P, P): Len(s_a -> s_b). From the empty tour, the site and
    insertion position with the largest J of the extended tour is added, until ``tour_sites`` sites or
    no site adds area.
    """
    L0 = config.tour_touch_cost_m
    P = len(start)
    left = w.copy()
    tour: list[int] = []
    gains: list[float] = []  # each site's new area, in tour order
    cost = 0.0
    while len(tour) < min(config.tour_sites, P):
        add = (cover @ left) * psi4  # (P,) new weighted area
        add[tour] = 0.0
        if add.max() <= 0.0:
            break
        # insertion at position i: before tour[i] (i = len(tour): at the end)
        best = (-1.0, -1, -1)
        for i in range(len(tour) + 1):
            into = start if i == 0 else hop[tour[i - 1]]  # (P,) cost to reach the new site
            if i < len(tour):
                nxt = tour[i]
                out = hop[:, nxt]
                old = start[nxt] if i == 0 else hop[tour[i - 1], nxt]
            else:
                out, old = np.zeros(P), 0.0
            # J(T + s) = (sum_i G_i + G(s | T)) / (Len(T) + Len(prev -> s) + Len(s -> next) - Len(prev -> next) + L0)
            J = (sum(gains) + add) / (cost + into + out - old + L0)
            J[add <= 0.0] = -1.0
            a = int(np.argmax(J))
            if J[a] > best[0]:
                best = (float(J[a]), a, i)
        _, a, i = best
        tour.insert(i, a)
        gains.insert(i, float(add[a]))
        left = left * (1.0 - cover[a])
        cost = float(start[tour[0]] + hop[tour[:-1], tour[1:]].sum()) + L0 * len(tour)
    return tour


def tour_plan(
    candidates_m: FloatArray,
    normals: FloatArray,
    contacts_m: FloatArray,
    r: FloatArray,
    v_n: FloatArray,
    R_z: FloatArray,
    config: PlannerConfig,
    variance: FloatArray | None = None,
) -> Tour:
    """Tour strategy (not in the paper): a receding-horizon tour through the candidates that explores the
    most weighted area per metre of travel; the planner touches its first site and replans after it.

    Patches and gains as in ``area_scores``, with the weights of ``patch_weights``: a site s explores
    the unexplored patches within rho, G(s) = Psi4(s) sum w(q). Travel between sites is IGEF's Psi2
    curve length (Eq. 15): Len(r -> s) from the fingertip leaving along -v_n, Len(s_i -> s_j) from a site
    leaving along its normal (the next retraction). The tour T = (s_1, ..., s_k) maximises, greedily,

        J(T) = sum_i G_i / (Len(r -> s_1) + sum_i Len(s_i -> s_i+1) + k L0)

    G_i the gain of s_i over the patches not explored by the sites before it, the tour built by
    ``greedy_insertion`` and put in its cheapest order (``best_order``). The pool is the ``tour_pool``
    candidates with the largest G(s) / (Len(r -> s) + L0) (one site tours are area's choice).
    A one-site tour is the myopic choice; a longer one goes first to the site on the way (a hole next
    to the path) and keeps a far uncovered region in the plan.
    A candidate within rho / 2 of a contact is no site (``SITE_AWAY``): its touch lands on ground
    explored already, and the patches it would add at the rim of its disc may stay unexplored when it
    lands a millimetre off (two such sites were touched in turn 700 times on the YCB wood blocks).
    When no candidate explores anything (or every one that does lies within rho / 2 of a contact),
    the tour is the single best of the distance to the nearest contact per unit of travel (as in
    area). Scores (m,): the tour's sites get J + k - i (i = 0 first),
    the other candidates G(s) / (Len(r -> s) + L0) scaled below J, so a caller that must skip the first
    site (its curve is blocked) takes the next one of the tour.
    candidates_m, normals (unit): (m, 3); contacts_m: (n, 3); r, v_n, R_z as in igef_terms; variance (m,).
    """
    L0 = config.tour_touch_cost_m
    rho = config.area_radius_m
    explored_by, _ = cKDTree(contacts_m).query(candidates_m)
    tree = cKDTree(candidates_m)
    w = patch_weights(candidates_m, explored_by, config, variance, tree)
    psi4 = rotation_factor(normals, R_z, config)  # Eq. 11
    reach = path_length(r, v_n, candidates_m, normals, config)  # Len(r -> s), (m,)
    gain = np.zeros(len(candidates_m))
    if w.any():
        pairs = tree.sparse_distance_matrix(tree, rho, output_type="ndarray")
        pairs = pairs[w[pairs["j"]] > 0.0]
        gain = np.bincount(pairs["i"], weights=w[pairs["j"]], minlength=len(candidates_m)) * psi4  # G(s)
        gain[explored_by < SITE_AWAY * rho] = 0.0
    if not gain.any():
        own = explored_by * psi4 / (reach + L0)
        index = int(np.argmax(own))
        scores = own / max(float(own.max()), 1e-300)
        scores[index] = 2.0
        return Tour(np.array([index]), np.zeros(1), float(reach[index] + L0), scores)
    own = gain / (reach + L0)
    pool = np.argsort(-own, kind="stable")[: config.tour_pool]
    pool = pool[gain[pool] > 0.0]
    P = len(pool)
    # cover[a, q]: pool site a explores patch q (within rho); weights of patches not yet explored
    row = np.full(len(candidates_m), -1)
    row[pool] = np.arange(P)
    in_pool = row[pairs["i"]] >= 0
    cover = np.zeros((P, len(candidates_m)))
    cover[row[pairs["i"][in_pool]], pairs["j"][in_pool]] = 1.0
    S, N = candidates_m[pool], normals[pool]
    # hop[a, b] = Len(s_a -> s_b), leaving s_a along its normal (v_n = -n_a)
    hop = bezier_length(
        approach_curve(S[:, None, :], -N[:, None, :], S[None, :, :], N[None, :, :], scale=config.psi2_control_scale)
    )
    start = reach[pool]
    tour = greedy_insertion(cover, w, psi4[pool], start, hop, config)
    sites = np.asarray(tour, dtype=np.int64)
    order = best_order(start[sites], hop[np.ix_(sites, sites)])
    sites = sites[order]
    # gains in the final order: each site over the patches the sites before it leave
    left = w.copy()
    ordered_gains = np.zeros(len(sites))
    for k, a in enumerate(sites):
        ordered_gains[k] = float(cover[a] @ left) * psi4[pool[a]]
        left = left * (1.0 - cover[a])
    total = float(start[sites[0]] + hop[sites[:-1], sites[1:]].sum()) + L0 * len(sites)
    J = float(ordered_gains.sum()) / total
    scores = J * own / max(float(own.max()), 1e-300) * 0.5
    chosen = pool[sites]
    scores[chosen] = J + len(chosen) - np.arange(len(chosen))
    return Tour(np.asarray(chosen, dtype=np.int64), ordered_gains, total, scores)


def away_from(points_m: ArrayLike, avoid_m: ArrayLike, radius_m: float) -> NDArray[np.bool_]:
    """Which points (m, 3) lie at least radius_m from every point of avoid_m (k, 3): a mask (m,)."""
    P = _points("points_m", points_m)
    A = np.asarray(avoid_m, dtype=np.float64).reshape(-1, 3)
    if len(A) == 0 or len(P) == 0 or radius_m <= 0.0:
        return np.ones(len(P), dtype=bool)
    dist, _ = cKDTree(A).query(P, distance_upper_bound=radius_m)
    return np.asarray(~np.isfinite(dist))


def curves_clear(
    vertices: ArrayLike,
    vertex_normals: ArrayLike,
    start_m: ArrayLike,
    v_n: ArrayLike,
    centres_m: ArrayLike,
    target_normals: ArrayLike,
    clearance_m: float,
    *,
    samples: int = 16,
    min_chord_m: float = 1e-4,
    max_reach_m: float = 0.03,
    tree: cKDTree | None = None,
) -> NDArray[np.bool_]:
    """Which fingertip curves keep clear of the estimated surface: a boolean mask (m,).

    Each curve is the one the controller runs (Eq. 15): from the fingertip centre ``start_m`` (3,),
    retracting along -v_n (3,), to the fingertip centre at the target ``centres_m`` (m, 3) reached
    against the target normal (m, 3). The estimated surface is the mesh ``vertices`` (k, 3) with outward
    unit ``vertex_normals`` (k, 3) (the local GPIS mesh); the signed distance of a point q is
    approximated by (q - v) . n_v at its nearest vertex v (negative inside). A curve is clear when that
    is >= ``clearance_m`` at ``samples`` points with tau in (0, 1) (the fingertip sphere of radius
    about clearance_m does not touch the estimate before the end); points farther than
    ``max_reach_m`` from every vertex (beyond the meshed patch) count as clear. Not in the paper.
    ``tree``: a ``cKDTree`` of ``vertices``, for callers that check several batches on one mesh.
    """
    V = _points("vertices", vertices)
    N = np.asarray(vertex_normals, dtype=np.float64)
    C = _points("centres_m", centres_m)
    if C.shape[0] == 0 or V.shape[0] == 0:
        return np.ones(C.shape[0], dtype=bool)
    P = approach_curve(start_m, v_n, C, target_normals, min_chord_m=min_chord_m)  # (m, 4, 3)
    tau = (np.arange(samples) + 0.5) / samples
    Q = bezier_point(P, tau).reshape(-1, 3)  # (m * samples, 3)
    dist, idx = (cKDTree(V) if tree is None else tree).query(Q, distance_upper_bound=max_reach_m)
    near = np.isfinite(dist)
    signed = np.full(len(Q), np.inf)
    signed[near] = np.einsum("ij,ij->i", Q[near] - V[idx[near]], N[idx[near]])
    return np.asarray(np.all(signed.reshape(C.shape[0], samples) >= clearance_m, axis=1))


@dataclass
class _CurveSurface:
    """What ``curves_clear`` checks the fingertip's curves against: the local mesh's vertices (k, 3) m and
    outward unit vertex normals (k, 3), the fingertip centre (3,) m, and (built on first use, once per
    plan) the vertices' k-d tree."""

    vertices_m: FloatArray
    vertex_normals: FloatArray
    fingertip_m: FloatArray

    @cached_property
    def tree(self) -> cKDTree:
        return cKDTree(self.vertices_m)


class Planner:
    """Chooses the next touch target among candidate surface points (Alg. 1 lines 13-18)."""

    def __init__(self, config: PlannerConfig | None = None) -> None:
        self.config = config or PlannerConfig()

    def sample(
        self, vertices: ArrayLike, normals: ArrayLike, variance: ArrayLike, last_contact: ArrayLike
    ) -> Candidates:
        """``sample_candidates`` with this strategy's step and radius (6 cm for GP-V, else 5 cm)."""
        cfg = self.config
        return sample_candidates(
            vertices, normals, variance, last_contact, step_m=cfg.candidate_step_m, radius_m=cfg.radius_m
        )

    def select(
        self,
        candidates_m: ArrayLike,
        normals: ArrayLike,
        variance: ArrayLike,
        contacts_m: ArrayLike,
        r: ArrayLike,
        v_n: ArrayLike,
        R_z: ArrayLike,
        rng: np.random.Generator,
        admissible: ArrayLike | None = None,
    ) -> Selection:
        """Rate the candidates and pick the best (igef, gpv) or a uniform one (random).

        candidates_m, normals: (m, 3); variance: (m,) GP variance; contacts_m: (n, 3), the last row is
        the last contact; r: fingertip position (3,); v_n: velocity direction before the last contact
        (3,, normalised here, zero allowed); R_z: fingertip poking axis (3,). Candidates further than
        the strategy's radius from the last contact are ignored (score 0), and so are those where the
        optional boolean mask ``admissible`` (m,) is False: not in the paper, a hook for the caller to
        drop targets whose Eq. 15 curve runs through the estimated object (GP-V picks the far side of
        small objects, and the straight-through curve touches again next to the start).
        Raises PlanningError when no candidate is left.
        """
        cfg = self.config
        S = _points("candidates_m", candidates_m)
        Nrm = _unit_rows("normals", normals) if S.shape[0] else np.zeros((0, 3))
        Q = np.asarray(variance, dtype=np.float64)
        C = _points("contacts_m", contacts_m)
        r_ = _vector("r", r)
        v = _vector("v_n", v_n)
        z = _vector("R_z", R_z)
        if Nrm.shape != S.shape or Q.shape != (S.shape[0],):
            raise PlanningError(f"normals {Nrm.shape} and variance {Q.shape} must match candidates {S.shape}")
        if C.shape[0] == 0:
            raise PlanningError("select needs at least one contact (the last contact centres the search)")
        v_norm = float(np.linalg.norm(v))
        v = v / v_norm if v_norm > 1e-12 else np.zeros(3)
        z_norm = float(np.linalg.norm(z))
        if z_norm < 1e-12:
            raise PlanningError("R_z has zero length; pass the fingertip's poking axis R[:, 2]")
        z = z / z_norm

        rel = S - C[-1]
        near = np.einsum("ij,ij->i", rel, rel) <= cfg.radius_m**2
        keep = near.copy()
        if admissible is not None:
            mask = np.asarray(admissible)
            if mask.shape != (S.shape[0],) or mask.dtype != np.bool_:
                raise PlanningError(f"admissible must be a boolean mask of shape ({S.shape[0]},), got {mask.shape}")
            keep &= mask
        valid = np.flatnonzero(keep)
        if valid.size == 0:
            raise PlanningError(
                f"no candidate target within {cfg.radius_m} m of the last contact {C[-1].tolist()} "
                f"({S.shape[0]} candidates given, {int(near.sum())} within it): "
                + (
                    "the curve to every one of these runs through the estimated surface"
                    if near.any()
                    else "the estimated surface's mesh has no vertex there (a part thinner than the GPIS node's "
                    "local_resolution_m even when refined, or a mesh made around another point)"
                )
            )
        if cfg.uses_variance and not np.all(np.isfinite(Q[valid])):
            raise PlanningError("variance holds NaN or infinity; the GP variance must be finite")
        scores = np.zeros(S.shape[0])
        psi: FloatArray | None = None
        if cfg.strategy == "igef":
            psi = np.zeros((S.shape[0], 4))
            psi[valid] = igef_terms(S[valid], Nrm[valid], C, r_, v, z, cfg)
            scores[valid] = psi[valid].prod(axis=1)  # Eq. 12: Psi = prod Psi_n
            index = int(valid[np.argmax(scores[valid])])
        elif cfg.strategy == "area":
            scores[valid] = area_scores(S[valid], Nrm[valid], C, r_, v, z, cfg, Q[valid])
            index = int(valid[np.argmax(scores[valid])])
        elif cfg.strategy == "tour":
            scores[valid] = tour_plan(S[valid], Nrm[valid], C, r_, v, z, cfg, Q[valid]).scores
            index = int(valid[np.argmax(scores[valid])])
        elif cfg.strategy == "gpv":
            scores[valid] = Q[valid]  # Alg. 1 line 14: I(s) = GP variance(s)
            index = int(valid[np.argmax(scores[valid])])
        else:
            scores[valid] = 1.0 / valid.size
            index = int(valid[rng.integers(valid.size)])
        return Selection(
            index=index,
            target_m=S[index].copy(),
            normal=Nrm[index].copy(),
            predicted_contact_m=S[index].copy(),
            score=float(scores[index]),
            scores=scores,
            psi=psi,
        )


@dataclass(frozen=True)
class Plan:
    """A planned touch: the candidates it was chosen among and the choice (scores over those candidates)."""

    candidates: Candidates
    selection: Selection


class TouchPlanner:
    """Algorithm 1 lines 11-18 with the rules not in the paper that PlannerConfig describes.

    Owns the contacts so far, the approach direction v_n of the last one and the targets whose touch
    landed elsewhere (unreached). ``plan`` runs once per contact, on the local surface that includes it.
    Events the node reports as counters (``take_counts``): ``no_admissible_candidate`` (every candidate
    was inadmissible, so the paper's choice among all of them was made) and ``no_clear_curve`` (no
    candidate curve keeps clear of the estimate, so the paper's choice was kept).
    """

    def __init__(self, config: PlannerConfig | None = None) -> None:
        self.planner = Planner(config)
        self.config = self.planner.config
        self.contacts: list[FloatArray] = []
        self.approach = np.zeros(3)
        self.normal = np.zeros(3)  # measured outward normal of the last contact (zero: not given)
        self.unreached: list[FloatArray] = []  # targets whose touch landed elsewhere
        self.planned_for = 0  # number of contacts the last plan was made for
        self.counts: Counter[str] = Counter()

    def add_touch(
        self,
        position_m: ArrayLike,
        predicted_contact_m: ArrayLike,
        approach_direction: ArrayLike,
        normal: ArrayLike = (0.0, 0.0, 0.0),
    ) -> None:
        """A touch at position_m (3,) m, aimed at predicted_contact_m (3,) m (NaN: no target), made
        moving along approach_direction (3,), the v_n of the next curve (unit, or zero for none), with
        the measured outward normal (3,) (unit, or zero when unknown: no slide starts from it).

        InputError (naming the TouchEvent field, the planner unchanged) for positions beyond the
        bounds of palpate.inputs or a direction that is neither unit nor zero."""
        position = np.array(coordinates(position_m, "position_m"))
        predicted = np.array(coordinates(predicted_contact_m, "predicted_contact_m", allow_nan=True))
        approach = np.array(unit_or_zero(approach_direction, "approach_direction"))
        measured = np.array(unit_or_zero(normal, "normal"))
        self.contacts.append(position)
        self.approach = approach
        self.normal = measured
        if np.all(np.isfinite(predicted)) and np.linalg.norm(position - predicted) > self.config.unreached_miss_m:
            self.unreached.append(predicted)

    def take_counts(self) -> dict[str, int]:
        """The events counted since the last call (name -> count), which are then forgotten."""
        if not self.counts:  # the usual tick: nothing to hand over, no new Counter
            return {}
        counts, self.counts = dict(self.counts), Counter()
        return counts

    def plan(
        self,
        region: str,
        num_contacts: int,
        vertices_m: FloatArray,
        vertex_normals: FloatArray,
        vertex_variance: FloatArray,
        fingertip: tuple[FloatArray, FloatArray] | None,
        rng: np.random.Generator,
        *,
        variance_vertices: NDArray[np.integer] | None = None,
    ) -> Plan | None:
        """The next touch, or None when this surface is not the one to plan on.

        Plans on a "local" surface (vertices (v, 3) m, outward unit vertex normals (v, 3), GP variance
        (k,) m^2 at the vertices variance_vertices (k,), default all) made from num_contacts contacts,
        when that is every contact so far and no plan was made for them yet. A strategy that rates the
        variance (``PlannerConfig.uses_variance``) samples its candidates among the vertices with a
        variance (the GPIS node gives it at GP-V's candidates), the others among all vertices.
        fingertip: its centre (3,) m and orientation (unit quaternion wxyz (4,); its z axis is the
        poking axis) now. Raises PlanningError
        when planning is due and there is no fingertip pose, or no candidate near the last contact.
        """
        if region != "local" or num_contacts != len(self.contacts) or self.planned_for == len(self.contacts):
            return None
        # a surface the planner cannot use is refused before anything changes (InputError)
        V = coordinates(vertices_m, "vertices_m")
        normals = unit_or_zero_rows(vertex_normals, "vertex_normals")
        if normals.shape != V.shape:
            raise InputError("vertex_normals", f"has {len(normals)} rows for {len(V)} vertices")
        sites = (
            np.arange(len(V))
            if variance_vertices is None
            else vertex_subset(variance_vertices, len(V), "variance_vertices")
        )
        Q = bounded(vertex_variance, "vertex_variance", MAX_COORDINATE_M**2, "m^2", lower=0.0)
        if Q.shape != sites.shape:
            raise InputError("vertex_variance", f"has {Q.size} values for {sites.size} variance_vertices")
        self.planned_for = len(self.contacts)
        if fingertip is None:
            raise PlanningError("no fingertip pose received yet; the simulation or driver must publish one")
        fingertip_m, quaternion_wxyz = fingertip
        axis = quat_to_matrix(quaternion_wxyz)[:, 2]
        cfg = self.config
        last = self.contacts[-1]
        if cfg.uses_variance and len(V) and not len(sites):
            raise PlanningError(
                f"the {cfg.strategy} strategy needs the GP variance on the surface, and this mesh carries "
                "none: set the gpis node's vertex_variance to candidates or all"
            )
        if not cfg.uses_variance:
            sites, Q = np.arange(len(V)), np.zeros(len(V))
        oriented = normals[sites].any(axis=1)  # a vertex where the GP's gradient vanishes is no candidate
        if not oriented.all():
            sites, Q = sites[oriented], Q[oriented]
        candidates = self.planner.sample(V[sites], normals[sites], Q, last)
        surface = _CurveSurface(V, normals, fingertip_m)
        contacts = np.array(self.contacts)
        admissible = None
        centres = candidates.points_m + cfg.tip_radius_m * candidates.normals  # fingertip centre at each target
        if len(candidates.points_m):
            hop = centres - fingertip_m
            admissible = np.einsum("ij,ij->i", hop, hop) >= cfg.min_hop_m**2
            admissible &= away_from(candidates.points_m, np.reshape(self.unreached, (-1, 3)), cfg.unreached_radius_m)
            if cfg.check_curves and cfg.strategy == "random":  # a uniform choice needs the whole mask
                admissible &= self._clear(surface, centres, candidates.normals, np.arange(len(centres)))
            if not admissible.any():  # nothing admissible: plan as the paper does
                self.counts["no_admissible_candidate"] += 1
                admissible = None
        # Psi2 measures the curve the controller will run: it starts at the last contact (c_p).
        args = (candidates.points_m, candidates.normals, candidates.variance, contacts, last, self.approach, axis)
        choice = self.planner.select(*args, rng, admissible=admissible)
        if cfg.check_curves and cfg.strategy != "random" and admissible is not None:
            choice = self._best_clear(choice, surface, candidates, centres, admissible)
        return Plan(candidates, replace(choice, slide=self._slides_to(choice)))

    def _slides_to(self, choice: Selection) -> bool:
        """Whether to slide to the chosen target: it lies within the strategy's slide reach of the last
        contact and its normal within slide_max_angle_deg of that contact's (PlannerConfig)."""
        cfg = self.config
        reach = cfg.slide_reach_m
        if reach <= 0.0 or not self.normal.any():
            return False
        near = float(np.linalg.norm(choice.target_m - self.contacts[-1])) <= reach
        return near and float(choice.normal @ self.normal) >= math.cos(math.radians(cfg.slide_max_angle_deg))

    def _clear(
        self, surface: _CurveSurface, centres: FloatArray, normals: FloatArray, rows: IntArray
    ) -> NDArray[np.bool_]:
        """curves_clear from the fingertip for the candidate rows ``rows``: boolean (len(rows),)."""
        cfg = self.config
        return curves_clear(
            surface.vertices_m,
            surface.vertex_normals,
            surface.fingertip_m,
            self.approach,
            centres[rows],
            normals[rows],
            cfg.tip_radius_m - cfg.curve_margin_m,
            samples=cfg.curve_samples,
            tree=surface.tree,
        )

    def _best_clear(
        self,
        choice: Selection,
        surface: _CurveSurface,
        candidates: Candidates,
        centres: FloatArray,
        mask: NDArray[np.bool_],
    ) -> Selection:
        """The best-scored candidate whose curve is clear, i.e. the argmax of the scores over the
        admissible candidates with clear curves: curves are checked in descending score order, 32 at a
        time, so usually only the first few are computed."""
        scores = choice.scores.copy()
        rel = candidates.points_m - self.contacts[-1]
        order = np.flatnonzero(mask & (np.einsum("ij,ij->i", rel, rel) <= self.config.radius_m**2))
        order = order[np.argsort(-scores[order], kind="stable")]
        for start in range(0, len(order), 32):
            rows = order[start : start + 32]
            clear = self._clear(surface, centres, candidates.normals, rows)
            scores[rows[~clear]] = 0.0
            if clear.any():
                index = int(rows[int(np.argmax(clear))])
                break
        else:  # no curve is clear: keep the paper's choice
            self.counts["no_clear_curve"] += 1
            return choice
        point = candidates.points_m[index].copy()
        return Selection(
            index=index,
            target_m=point,
            normal=candidates.normals[index] / np.linalg.norm(candidates.normals[index]),
            predicted_contact_m=point.copy(),
            score=float(scores[index]),
            scores=scores,
            psi=choice.psi,
        )
