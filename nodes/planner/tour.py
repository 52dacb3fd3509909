"""The tour strategy (not in the paper): a receding-horizon tour through the candidates that explores
the most weighted area per metre of travel (``tour_plan``); the planner touches its first site."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from itertools import permutations

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from palpate.geometry.bezier import approach_curve, bezier_length
from palpate.nodes.planner.config import PlannerConfig
from palpate.nodes.planner.scores import hole_weights, leave_covered, path_length, rotation_factor, variance_factor

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


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
    w *= variance_factor(variance, config.tour_variance_weight)
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


def tour_cost_m(sites: Sequence[int] | IntArray, start: FloatArray, hop: FloatArray, touch_cost_m: float) -> float:
    """The travel of a tour through the pool rows ``sites`` (k >= 1,) in visiting order, touch costs
    included: Len(r -> s_1) + sum_i Len(s_i -> s_i+1) + k L0, with start (P,) = Len(r -> s_a) and
    hop (P, P) = Len(s_a -> s_b)."""
    rows = np.asarray(sites, dtype=np.int64)
    return float(start[rows[0]] + hop[rows[:-1], rows[1:]].sum()) + touch_cost_m * len(rows)


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
        cost = tour_cost_m(tour, start, hop, L0)
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
        own = leave_covered(explored_by, psi4, reach + L0)
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
    total = tour_cost_m(sites, start, hop, L0)
    J = float(ordered_gains.sum()) / total
    scores = J * own / max(float(own.max()), 1e-300) * 0.5
    chosen = pool[sites]
    scores[chosen] = J + len(chosen) - np.arange(len(chosen))
    return Tour(np.asarray(chosen, dtype=np.int64), ordered_gains, total, scores)
