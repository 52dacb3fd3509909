"""Next-best-touch selection (paper 002, Sections 2.3-2.4, Eqs. 7-12, Algorithm 2).

The planner sees the estimated surface only as arrays: candidate points on the surface mesh, their
outward unit normals and the GP variance there. ``sample_candidates`` thins the mesh near the last
contact; ``Planner.select`` rates the candidates with the configured strategy and picks one.
``TouchPlanner`` is the planner node's whole decision: it remembers the contacts, plans once per
contact when the local surface that includes it arrives, and drops targets it cannot usefully reach
(admissibility rules not in the paper, see PlannerConfig).

Conventions: metres; the fingertip's local z axis ``R_z`` is the direction it pokes (it faces a surface
with outward normal n when ``R_z = -n``); ``v_n`` is the unit velocity just before the last contact.
The strategies' ratings are in ``scores`` (IGEF, area) and ``tour`` (tour), the admissibility checks
in ``curves``, the parameters in ``config``.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from palpate.errors import InputError, PlanningError
from palpate.geometry.rotations import quat_to_matrix
from palpate.geometry.thinning import thin_near
from palpate.inputs import (
    MAX_COORDINATE_M,
    bounded,
    coordinates,
    unit_or_zero,
    unit_or_zero_rows,
    unit_quaternion,
    vertex_subset,
)
from palpate.nodes.planner.checks import points, unit_rows, vector
from palpate.nodes.planner.config import PlannerConfig
from palpate.nodes.planner.curves import CurveSurface, away_from, curves_clear
from palpate.nodes.planner.scores import area_scores, igef_terms
from palpate.nodes.planner.tour import tour_plan

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


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
    V = points("vertices", vertices)
    N = np.asarray(normals, dtype=np.float64)
    Q = np.asarray(variance, dtype=np.float64)
    c = vector("last_contact", last_contact)
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


def _near(points_m: FloatArray, centre_m: FloatArray, radius_m: float) -> NDArray[np.bool_]:
    """Which points (m, 3) lie within radius_m of centre_m (3,): a mask (m,)."""
    rel = points_m - centre_m
    return np.einsum("ij,ij->i", rel, rel) <= radius_m**2


def _surface(
    vertices_m: ArrayLike,
    vertex_normals: ArrayLike,
    vertex_variance: ArrayLike,
    variance_vertices: ArrayLike | None,
) -> tuple[FloatArray, FloatArray, IntArray, FloatArray]:
    """A local surface checked as the planner needs it: vertices (v, 3) m, normals (v, 3) (unit or
    zero), the vertices with a variance (k,) (default all) and that variance (k,) m^2. A surface the
    planner cannot use is an InputError naming the SurfaceMesh field."""
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
    return V, normals, sites, Q


@dataclass(frozen=True)
class _Query:
    """``Planner.select``'s arguments, checked: candidates (m, 3) m with unit normals (m, 3) and GP
    variance (m,), contacts (n >= 1, 3) m, fingertip position r (3,) m, v_n (3,, unit or zero) and the
    unit poking axis R_z (3,)."""

    points_m: FloatArray
    normals: FloatArray
    variance: FloatArray
    contacts_m: FloatArray
    r_m: FloatArray
    v_n: FloatArray
    R_z: FloatArray


def _query(
    S: ArrayLike, N: ArrayLike, Q: ArrayLike, C: ArrayLike, r: ArrayLike, v_n: ArrayLike, R_z: ArrayLike
) -> _Query:
    """``Planner.select``'s candidates_m, normals, variance, contacts_m, r, v_n and R_z, checked in that
    order (PlanningError names the argument); v_n and R_z normalised."""
    points_m = points("candidates_m", S)
    normals = unit_rows("normals", N) if points_m.shape[0] else np.zeros((0, 3))
    variance = np.asarray(Q, dtype=np.float64)
    contacts_m = points("contacts_m", C)
    r_m = vector("r", r)
    v = vector("v_n", v_n)
    z = vector("R_z", R_z)
    if normals.shape != points_m.shape or variance.shape != (points_m.shape[0],):
        raise PlanningError(
            f"normals {normals.shape} and variance {variance.shape} must match candidates {points_m.shape}"
        )
    if contacts_m.shape[0] == 0:
        raise PlanningError("select needs at least one contact (the last contact centres the search)")
    v_norm = float(np.linalg.norm(v))
    v = v / v_norm if v_norm > 1e-12 else np.zeros(3)
    z_norm = float(np.linalg.norm(z))
    if z_norm < 1e-12:
        raise PlanningError("R_z has zero length; pass the fingertip's poking axis R[:, 2]")
    return _Query(points_m, normals, variance, contacts_m, r_m, v, z / z_norm)


class Planner:
    """Chooses the next touch target among candidate surface points (Alg. 1 lines 13-18)."""

    def __init__(self, config: PlannerConfig | None = None) -> None:
        self.config = config or PlannerConfig()

    def sample(
        self, vertices: ArrayLike, normals: ArrayLike, variance: ArrayLike, last_contact: ArrayLike
    ) -> Candidates:
        """``sample_candidates`` with this strategy's step and radius (``PlannerConfig.radius_m``: 6 cm
        for GP-V and the tour, else 5 cm)."""
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
        """Rate the candidates with the configured strategy and pick the best-rated one (igef, gpv, area,
        tour) or a uniform one (random).

        candidates_m, normals: (m, 3); variance: (m,) GP variance; contacts_m: (n, 3), the last row is
        the last contact; r: fingertip position (3,); v_n: velocity direction before the last contact
        (3,, normalised here, zero allowed); R_z: fingertip poking axis (3,). Candidates further than
        the strategy's radius from the last contact are ignored (score 0), and so are those where the
        optional boolean mask ``admissible`` (m,) is False: not in the paper, the hook for the caller's
        admissibility rules (TouchPlanner: targets the fingertip barely leaves for, targets it could not
        reach before, curves that run through the estimated object).
        Raises PlanningError when no candidate is left.
        """
        query = _query(candidates_m, normals, variance, contacts_m, r, v_n, R_z)
        valid = self._valid(query, admissible)
        ratings, terms = self._rate(query, valid)
        pick = int(rng.integers(valid.size)) if self.config.strategy == "random" else int(np.argmax(ratings))
        index = int(valid[pick])
        m = query.points_m.shape[0]
        scores = np.zeros(m)
        scores[valid] = ratings
        psi: FloatArray | None = None
        if terms is not None:
            psi = np.zeros((m, 4))
            psi[valid] = terms
        return Selection(
            index=index,
            target_m=query.points_m[index].copy(),
            normal=query.normals[index].copy(),
            predicted_contact_m=query.points_m[index].copy(),
            score=float(scores[index]),
            scores=scores,
            psi=psi,
        )

    def _valid(self, query: _Query, admissible: ArrayLike | None) -> IntArray:
        """The rows (k >= 1,) of the candidates within the strategy's radius of the last contact that
        ``admissible`` (a boolean mask (m,), or None) admits; PlanningError when none is left."""
        cfg = self.config
        S, last = query.points_m, query.contacts_m[-1]
        near = _near(S, last, cfg.radius_m)
        keep = near
        if admissible is not None:
            mask = np.asarray(admissible)
            if mask.shape != (S.shape[0],):
                raise PlanningError(f"admissible must be a boolean mask of shape ({S.shape[0]},), got {mask.shape}")
            if mask.dtype != np.bool_:
                raise PlanningError(f"admissible must be a boolean mask, got dtype {mask.dtype}")
            keep = near & mask
        valid = np.flatnonzero(keep)
        if valid.size == 0:
            raise PlanningError(
                f"no candidate target within {cfg.radius_m} m of the last contact {last.tolist()} "
                f"({S.shape[0]} candidates given, {int(near.sum())} within it): "
                + (
                    "the curve to every one of these runs through the estimated surface"
                    if near.any()
                    else "the estimated surface's mesh has no vertex there (a part thinner than the GPIS node's "
                    "local_resolution_m even when refined, or a mesh made around another point)"
                )
            )
        return valid

    def _rate(self, query: _Query, valid: IntArray) -> tuple[FloatArray, FloatArray | None]:
        """The strategy's rating of the candidate rows ``valid`` (k,), and for IGEF its factors
        Psi1..Psi4 (k, 4) (None for the other strategies)."""
        cfg = self.config
        Q = query.variance[valid]
        if cfg.uses_variance and not np.all(np.isfinite(Q)):
            raise PlanningError("variance holds NaN or infinity; the GP variance must be finite")
        S, N, C = query.points_m[valid], query.normals[valid], query.contacts_m
        motion = (query.r_m, query.v_n, query.R_z)
        if cfg.strategy == "igef":
            psi = igef_terms(S, N, C, *motion, cfg)
            return psi.prod(axis=1), psi  # Eq. 12: Psi = prod Psi_n
        if cfg.strategy == "area":
            return area_scores(S, N, C, *motion, cfg, Q), None
        if cfg.strategy == "tour":
            return tour_plan(S, N, C, *motion, cfg, Q).scores, None
        if cfg.strategy == "gpv":
            return Q, None  # Alg. 1 line 14: I(s) = GP variance(s)
        if cfg.strategy == "random":
            return np.full(valid.size, 1.0 / valid.size), None  # uniform
        # a name added to Strategy without a rating here would otherwise fall through to a uniform one
        raise PlanningError(f"strategy {cfg.strategy!r} has no rating in Planner._rate")


@dataclass(frozen=True)
class Plan:
    """A planned touch: the candidates it was chosen among and the choice (scores over those candidates)."""

    candidates: Candidates
    selection: Selection


def _check_reaches(vertices_m: FloatArray, last_m: FloatArray, radius_m: float, num_contacts: int) -> None:
    """PlanningError naming what the local surface (v, 3) lacks when none of its vertices lies within radius_m
    of the last contact (3,): an empty mesh, or one made elsewhere or in other units (a driver's)."""
    if len(vertices_m) == 0:
        raise PlanningError(f"the local surface of {num_contacts} contacts holds no vertex: nothing to plan on")
    nearest = float(np.sqrt(np.min(np.sum((vertices_m - last_m) ** 2, axis=1))))
    if nearest > radius_m:
        raise PlanningError(
            f"no vertex of the local surface of {num_contacts} contacts lies within {radius_m} m of the last contact "
            f"{last_m.tolist()}: the nearest is {nearest:.3g} m away (a mesh made around another point, or in units "
            "other than metres)"
        )


class TouchPlanner:
    """Algorithm 1 lines 11-18 with the rules not in the paper that PlannerConfig describes.

    Owns the contacts so far, the approach direction v_n of the last one and the targets whose touch
    landed elsewhere (unreached). ``plan`` runs once per contact, on the local surface that includes it.
    Events the node reports as counters (``take_counts``): ``no_admissible_candidate`` (every candidate
    was inadmissible, so the paper's choice among all of them was made), ``no_clear_curve`` (no
    candidate curve keeps clear of the estimate, so the paper's choice was kept) and
    ``surface_not_matching`` (a local surface of another number of contacts than the touches so far,
    ``unmatched``: not planned on).
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
        #: (num_contacts, touches) of the last local surface made of other contacts than the touches so far
        self.unmatched: tuple[int, int] | None = None

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
        if region not in ("local", "global"):
            raise InputError("region", f"{region!r} is no region of a surface: 'local' (a touch's) or 'global'")
        if region != "local" or self.planned_for == len(self.contacts):
            return None
        if num_contacts != len(self.contacts):  # a surface of other contacts: this touch's is still to come
            self.counts["surface_not_matching"] += 1
            self.unmatched = (num_contacts, len(self.contacts))
            return None
        # a surface the planner cannot use is refused before anything changes (InputError)
        V, normals, sites, Q = _surface(vertices_m, vertex_normals, vertex_variance, variance_vertices)
        if fingertip is not None:  # so is a pose
            fingertip = (coordinates(fingertip[0], "position_m"), unit_quaternion(fingertip[1], "quaternion_wxyz"))
        self.planned_for = len(self.contacts)
        if fingertip is None:
            raise PlanningError("no fingertip pose received yet; the simulation or driver must publish one")
        fingertip_m, quaternion_wxyz = fingertip
        axis = quat_to_matrix(quaternion_wxyz)[:, 2]
        cfg = self.config
        _check_reaches(V, self.contacts[-1], cfg.radius_m, num_contacts)
        candidates = self._candidates(V, normals, sites, Q)
        surface = CurveSurface(V, normals, fingertip_m)
        centres = candidates.points_m + cfg.tip_radius_m * candidates.normals  # fingertip centre at each target
        admissible = self._admissible(candidates, centres, surface)
        # Psi2 measures the curve the controller will run: it starts at the last contact (c_p).
        choice = self.planner.select(
            candidates.points_m,
            candidates.normals,
            candidates.variance,
            np.array(self.contacts),
            self.contacts[-1],
            self.approach,
            axis,
            rng,
            admissible=admissible,
        )
        if cfg.check_curves and cfg.strategy != "random" and admissible is not None:
            choice = self._best_clear(choice, surface, candidates, centres, admissible)
        return Plan(candidates, replace(choice, slide=self._slides_to(choice)))

    def _candidates(self, V: FloatArray, normals: FloatArray, sites: IntArray, Q: FloatArray) -> Candidates:
        """The candidates on the surface (vertices V (v, 3) m, normals (v, 3), GP variance Q (k,) at the
        vertices ``sites`` (k,)): among the vertices with a variance for a strategy that rates it, else
        among all; none where the normal is zero. PlanningError when the strategy needs a variance the
        mesh does not carry."""
        cfg = self.config
        if cfg.uses_variance and len(V) and not len(sites):
            raise PlanningError(
                f"the {cfg.strategy} strategy needs the GP variance on the surface, and this mesh carries "
                "none: set the gpis node's vertex_variance to candidates, all or auto (which gives it to a planner "
                "that rates by it)"
            )
        if not cfg.uses_variance:
            sites, Q = np.arange(len(V)), np.zeros(len(V))
        oriented = normals[sites].any(axis=1)  # a vertex where the GP's gradient vanishes is no candidate
        if not oriented.all():
            sites, Q = sites[oriented], Q[oriented]
        return self.planner.sample(V[sites], normals[sites], Q, self.contacts[-1])

    def _admissible(
        self, candidates: Candidates, centres: FloatArray, surface: CurveSurface
    ) -> NDArray[np.bool_] | None:
        """Which candidates the rules of PlannerConfig admit (min_hop_m, unreached_radius_m and, for the
        random strategy, whose uniform choice needs the whole mask, check_curves): a mask (m,), given
        the fingertip centre at each target (m, 3). None when there is no candidate, or when none is
        admissible: the paper's choice among all of them is then made (and counted)."""
        cfg = self.config
        if not len(candidates.points_m):
            return None
        hop = centres - surface.fingertip_m
        admissible = np.einsum("ij,ij->i", hop, hop) >= cfg.min_hop_m**2
        admissible &= away_from(candidates.points_m, np.reshape(self.unreached, (-1, 3)), cfg.unreached_radius_m)
        if cfg.check_curves and cfg.strategy == "random":
            admissible &= self._clear(surface, centres, candidates.normals, np.arange(len(centres)))
        if not admissible.any():
            self.counts["no_admissible_candidate"] += 1
            return None
        return admissible

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
        self, surface: CurveSurface, centres: FloatArray, normals: FloatArray, rows: IntArray
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
        surface: CurveSurface,
        candidates: Candidates,
        centres: FloatArray,
        mask: NDArray[np.bool_],
    ) -> Selection:
        """The best-scored candidate whose curve is clear, i.e. the argmax of the scores over the
        admissible candidates with clear curves: curves are checked in descending score order, 32 at a
        time, so usually only the first few are computed."""
        scores = choice.scores.copy()
        order = np.flatnonzero(mask & _near(candidates.points_m, self.contacts[-1], self.config.radius_m))
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
