"""How the strategies rate candidate targets: IGEF's factors Psi1..Psi4 (paper 002, Eqs. 7-12,
Algorithm 2) and the area strategy's new explored area per unit of travel (not in the paper).

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

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist

from palpate.geometry.bezier import approach_curve, bezier_length
from palpate.nodes.planner.config import PlannerConfig

FloatArray = NDArray[np.float64]


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
    # Eqs. 8-9, Alg. 2 line 4: Psi2(s) = 1 / Len(bezier(r, r - beta v_n, s_p + beta s_n, s_p))
    psi2 = 1.0 / np.maximum(path_length(r, v_n, candidates_m, normals, config), config.min_path_m)
    psi4 = rotation_factor(normals, R_z, config)  # Eq. 11
    psi1, psi3 = contact_terms(candidates_m, contacts_m, config)
    return np.stack([psi1, psi2, psi3, psi4], axis=1)


#: Above this many contacts IGEF's Psi3 reads only the contacts within its reach of the candidates
#: (``contact_terms``): the dense distances grew with the history (45-205 ms a plan at 10,000 contacts
#: on a large object). At or below it, every contact (every evaluation of the 30 shared objects stays
#: below: their contact budgets are at most about 1,500).
NEAR_CONTACTS_ABOVE = 2000
#: Psi3's terms beyond mu3 + this many sigma3 are below exp(-36) = 2.3e-16 each, and left out.
PSI3_REACH_SIGMAS = 6.0


def contact_terms(
    candidates_m: FloatArray, contacts_m: FloatArray, config: PlannerConfig
) -> tuple[FloatArray, FloatArray]:
    """IGEF's Psi1 and Psi3 (Eqs. 7 and 10) of every candidate (m, 3) from the contacts (n, 3), n >= 1.

    Above NEAR_CONTACTS_ABOVE contacts only those within Psi3's reach (mu3 + PSI3_REACH_SIGMAS sigma3)
    of the candidates' bounding sphere count: Psi3 loses terms below exp(-36) each, and a candidate whose
    nearest contact is not among them (farther than the reach) takes its Psi1 from all contacts."""
    near = contacts_m
    reach = config.mu3_m + PSI3_REACH_SIGMAS * config.sigma3_m
    if len(contacts_m) > NEAR_CONTACTS_ABOVE:
        centre = 0.5 * (candidates_m.min(axis=0) + candidates_m.max(axis=0))
        radius = float(np.sqrt(np.max(np.sum((candidates_m - centre) ** 2, axis=1))))
        near = contacts_m[np.sum((contacts_m - centre) ** 2, axis=1) <= (reach + radius) ** 2]
        if len(near) == 0:
            near = contacts_m[:1]
    d = cdist(candidates_m, near)  # |s_p - c_p|, (m, n)
    nearest = d.min(axis=1)
    if len(near) < len(contacts_m) and np.any(beyond := nearest > reach):
        nearest[beyond] = cdist(candidates_m[beyond], contacts_m).min(axis=1)
    # Eq. 7, Alg. 2 line 2: Psi1(s) = min_c 1 - exp(-|s_p - c_p|^2 / sigma1^2) (monotone in |s - c|)
    psi1 = 1.0 - np.exp(-(nearest**2) / config.sigma1_m**2)
    # Eq. 10, Alg. 2 line 3: Psi3(s) = sum_c exp(-(|s - c| - mu3)^2 / sigma3^2), in place on d (m x n)
    d -= config.mu3_m
    d *= 1.0 / config.sigma3_m
    np.square(d, out=d)
    np.negative(d, out=d)
    np.exp(d, out=d)
    return psi1, d.sum(axis=1)


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
        area = np.bincount(pairs["i"], weights=weight[pairs["j"]], minlength=len(candidates_m))
        gain = area * variance_factor(variance, config.area_variance_weight)
        if gain.max() > 0.0:
            return np.asarray(gain * psi4 / cost, dtype=np.float64)
    return leave_covered(explored_by, psi4, cost)


def variance_factor(variance: FloatArray | None, weight: float) -> FloatArray | float:
    """The variance term of a gain or patch weight, 1 + kappa var / max var, for the GP variance (m,)
    and the weight kappa (``area_variance_weight``, ``tour_variance_weight``): among equal new areas
    the least known first. 1 when kappa is 0 or there is no positive variance."""
    if weight > 0.0 and variance is not None and variance.max() > 0.0:
        return 1.0 + weight * variance / variance.max()
    return 1.0


def leave_covered(explored_by: FloatArray, psi4: FloatArray, cost_m: FloatArray) -> FloatArray:
    """The rating when no candidate explores anything (the local surface is covered): the distance to
    the nearest contact explored_by (m,) per unit of travel cost_m (m,), times Psi4 (m,), which leads
    out of the covered region (area and tour strategies)."""
    return np.asarray(explored_by * psi4 / cost_m, dtype=np.float64)
