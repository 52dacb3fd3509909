"""Local GP experts on a voxel partition, blended by a smooth partition of unity (issue 11, item 2).

Why this approximation. The exact GPIS (``core.GPIS``) costs O(n^2) per contact and O(n) per mean
query and O(n^2) per variance query, with an O(n^2) factor in memory (12.8 GB at 10,000 contacts).
Of the three scalable families the issue names, inducing points smooth away the millimetre detail
that the surface error budget (0.2 mm p95) is about, and a compactly supported kernel changes the
model itself (no longer the thin-plate GP of paper 002). Local experts keep the exact model and are
only wrong through what they leave out: contacts far from a query point, which the thin-plate GP
screens almost completely once nearby contacts pin the surface (ShapeMap 3-D's local GPs, and
partition-of-unity implicit surfaces, rely on the same locality). Each expert is an exact
``GPIS`` over the contacts of its region, so a new contact updates only the few experts whose
region holds it: the cost per touch depends on the local contact density, not on the history.

Partition. Expert i owns the voxel [h i, h (i + 1)) (per axis; h = local_cell_m). Its weight is 1
inside the voxel except within a band of half-width b = local_blend_m around each face, where it
hands over smoothly to the neighbour. Per axis, with t = x / h, i = floor(t), u = t - i, beta = b / h:

    u < beta:       cells (i - 1, i),  v = (u + beta) / (2 beta)
    u > 1 - beta:   cells (i, i + 1),  v = (u - 1 + beta) / (2 beta)
    otherwise:      cell i alone (v = 0)
    w_upper = s(v),  w_lower = 1 - s(v),  s(v) = 3 v^2 - 2 v^3 (smoothstep: C1, s(0.5) = 0.5)

and the weight of an expert is the product over the three axes: one expert for most points, two
to eight near voxel faces, edges and corners; the weights sum to 1 and have continuous gradients
(d w_upper / dx = s'(v) / (2 b)). Expert i holds every contact within b + local_margin_m of its
voxel on each axis, so each point it weighs has data on every side up to at least local_margin_m.
An expert that grows past local_max_contacts halves its own margin (to 0 once below b / 4) and is
rebuilt from the contacts in its smaller box: where contacts are dense the data a few millimetres
around a point pin the surface (one left with no contact in its box leaves the table, and the far
field takes its weight). An expert still over the cap at margin 0 (a voxel touched again and
again) keeps one contact per cube of edge s, the first to arrive, from s = h / 8 doubling until it
holds at most local_max_contacts; later contacts in an occupied cube leave it as it is. So the cap
bounds both the cost per touch and the memory, whatever the history.

Blending. With a set E(x) of experts that exist (hold at least one contact) and the weight left over
w_far = 1 - sum_{i in E} w_i taken by a far-field expert (an exact GPIS over one contact per voxel of
edge local_far_cell_m, the first to arrive, so that empty regions deep inside or far outside keep
the sign that the whole object gives them; past local_far_max_contacts its edge doubles and it keeps
the first contact of each larger voxel, which is in it already), and the shared prior mean m(x) of
Eq. 2:

    f(x)      = m(x) + sum_i w_i(x) r_i(x) + w_far(x) r_far(x)        (r = an expert's f - m)
    grad f(x) = grad m(x) + sum_i [w_i grad r_i + r_i grad w_i] + w_far grad r_far + r_far grad w_far,
                grad w_far = -sum_{i in E} grad w_i
    var f(x) ~= sum_i w_i(x) var_i(x) + w_far(x) var_far(x)     (a mixture of the experts' Eq. 6)

The mean and gradient are exactly the derivative pair of one smooth function; the variance is the
usual mixture-of-experts estimate (each expert's Eq. 6 with its own contacts: it can only exceed
the exact GP's, by what the left-out far contacts would have explained). The mean and gradient of
all experts in play are contracted in one compiled loop (``local_kernels``); the variance takes one
triangular solve per expert with every query point it weighs. Errors against the exact
GP are measured in tests/unit/gpis/test_local.py and by `palpate bench gpis`.
"""

from __future__ import annotations

from contextlib import AbstractContextManager
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from palpate.errors import EstimationError
from palpate.nodes.gpis.core import (
    GPIS,
    GPISConfig,
    PriorMean,
    _points,
    _unit_normals,
    first_centre,
    one_contact,
    prior_gradient,
    prior_mean,
)
from palpate.nodes.gpis.expert_pack import FAR_SLOT, ExpertPack
from palpate.nodes.gpis.kernels import IsotropicKernel
from palpate.nodes.gpis.local_kernels import (
    blend_pairs,
    column_sums_of_squares,
    contract_pairs,
    value_obs_blocks,
)

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

# Keys pack a voxel index (each |i| < 2^20) into one int64 for np.unique.
_KEY_BITS = 21
_KEY_OFFSET = 1 << (_KEY_BITS - 1)
_KEY_MASK = (1 << _KEY_BITS) - 1
#: Largest batch added in one atomic step (larger ones are split).
BATCH = 256


def _pack(idx: IntArray) -> IntArray:
    """Voxel indices (..., 3) -> int64 keys (...)."""
    i = idx + _KEY_OFFSET
    return (i[..., 0] << (2 * _KEY_BITS)) | (i[..., 1] << _KEY_BITS) | i[..., 2]


def _voxel_keys(P: FloatArray, cell_m: float) -> IntArray:
    """Keys (n,) of the voxels of edge cell_m that hold the points P (n, 3)."""
    return _pack(np.floor(P / cell_m).astype(np.int64))


class LocalGPIS:
    """Partition-of-unity blend of exact GPIS experts on a voxel grid (see the module docstring).

    Same interface as ``GPIS`` for updates and queries. Not thread-safe; updates are atomic.
    """

    def __init__(self, config: GPISConfig | None = None, *, prior_centre_m: ArrayLike | None = None) -> None:
        self.config = config if config is not None else GPISConfig()
        self.kernel: IsotropicKernel = self.config.make_kernel()
        self.cell_m = self.config.local_cell_m
        self.blend_m = self.config.local_blend_m
        self.margin_m = self.config.local_margin_m
        self._centre: FloatArray | None = None
        if prior_centre_m is not None:
            self._centre = _points(prior_centre_m, "prior_centre_m")[0].copy()
        self._experts: dict[int, GPIS] = {}
        self._margins: dict[int, float] = {}  # experts whose margin shrank (default: margin_m)
        #: experts thinned at margin 0: key -> (cube edge s, the cubes it holds a contact of)
        self._thinned: dict[int, tuple[float, set[tuple[int, int, int]]]] = {}
        self._pack = ExpertPack()  # every expert's contacts and weights, for the compiled loops
        self._far: GPIS | None = None
        self._far_cell_m = self.config.local_far_cell_m
        self._far_cells: set[int] = set()
        self._P = np.zeros((0, 3))
        self._N = np.zeros((0, 3))
        self._count = 0

    # --- state -------------------------------------------------------------------------------------
    @property
    def n_contacts(self) -> int:
        return self._count

    @property
    def positions_m(self) -> FloatArray:
        """Contact positions (n, 3), a copy."""
        return self._P[: self._count].copy()

    @property
    def normals(self) -> FloatArray:
        """Contact unit normals (n, 3), a copy."""
        return self._N[: self._count].copy()

    @property
    def supports_free_space(self) -> bool:
        return False

    def add_free_space(self, points_m: ArrayLike, distance_m: float) -> None:
        """Refused: the experts hold contacts only (``supports_free_space`` is False)."""
        raise EstimationError("the local GPIS takes no free-space observations; use the exact estimator")

    def drop_free_space(self) -> None:
        """Nothing to drop (it takes none)."""

    @property
    def supports_replaced_prior(self) -> bool:
        return False

    @property
    def prior_replaced(self) -> bool:
        return False

    def replaced_prior(self, prior: PriorMean) -> AbstractContextManager[None]:
        """Refused: each expert and the far field hold residuals of the shared prior."""
        raise EstimationError("the local GPIS cannot replace its prior; use the exact estimator")

    @property
    def prior_centre_m(self) -> FloatArray | None:
        return None if self._centre is None else self._centre.copy()

    @property
    def n_experts(self) -> int:
        return len(self._experts)

    def expert_sizes(self) -> list[int]:
        """Contacts held by each expert."""
        return [e.n_contacts for e in self._experts.values()]

    @property
    def factor_bytes(self) -> int:
        """Memory of every expert's Cholesky buffer (bytes)."""
        experts = list(self._experts.values()) + ([self._far] if self._far is not None else [])
        return sum(e.factor_bytes for e in experts)

    # --- updates -----------------------------------------------------------------------------------
    def add_contact(self, position_m: ArrayLike, normal: ArrayLike) -> None:
        """Add one contact: position (3,) in metres and outward normal (3,) (normalised here)."""
        self.add_contacts(*one_contact(position_m, normal))

    def add_contacts(self, positions_m: ArrayLike, normals: ArrayLike) -> None:
        """Add b contacts (b, 3): each goes to the experts whose region holds it (and maybe the far field).

        Atomic: when one expert's update fails, the experts already updated are cut back to their
        earlier contacts (``GPIS.truncate``, exact) and the error is raised. A batch of more than
        BATCH contacts is added BATCH at a time (each chunk atomic), so that experts over
        local_max_contacts shrink as they fill and the peak memory stays that of the capped experts.
        """
        P = _points(positions_m, "contact positions")
        N = _unit_normals(normals, len(P))
        reach = self.cell_m * (_KEY_OFFSET - 16)  # voxel keys hold indices below 2^20 (and queries near)
        if len(P) and float(np.abs(P).max()) > reach:
            raise EstimationError(
                f"a contact lies {float(np.abs(P).max()):.6g} m from the origin, beyond the local estimator's "
                f"reach of {reach:.6g} m with local_cell_m = {self.cell_m:g}; use a larger local_cell_m or the exact "
                "estimator"
            )
        if len(P) > BATCH:
            for s in range(0, len(P), BATCH):
                self.add_contacts(P[s : s + BATCH], N[s : s + BATCH])
            return
        if len(P) == 0:
            return
        centre = first_centre(self.config, self._centre, P, N)
        groups = self._filter_by_margin(P, self._memberships(P))
        far_new = self._far_members(P)
        # Update every expert concerned; on failure, cut the ones already updated back (GPIS.truncate).
        sizes = {key: e.n_contacts for key, e in self._experts.items() if key in groups}
        staged: dict[int, GPIS] = {}
        far = self._far if self._far is not None else GPIS(self.config, prior_centre_m=centre)
        far_size = far.n_contacts
        coarse: tuple[GPIS, float, set[int]] | None = None
        try:
            for key, rows in groups.items():
                expert = self._experts.get(key)
                if expert is None:
                    expert = staged[key] = GPIS(self.config, prior_centre_m=centre)
                expert.add_contacts(P[rows], N[rows])
            if far_new.size:
                far.add_contacts(P[far_new], N[far_new])
            if far.n_contacts > self.config.local_far_max_contacts:
                coarse = self._coarsened_far(far)
        except EstimationError:
            for key, size in sizes.items():
                self._experts[key].truncate(size)
            far.truncate(far_size)
            raise
        self._experts.update(staged)
        for key in groups:
            self._pack.set(key, self._experts[key])
        if coarse is not None:
            far, self._far_cell_m, self._far_cells = coarse
        else:
            self._far_cells.update(int(k) for k in _voxel_keys(P[far_new], self._far_cell_m))
        self._far = far
        if far_new.size or coarse is not None:
            self._pack.set(None, far)
        self._centre = centre
        self._note_held(P, groups)
        self._append(P, N)
        for key in groups:
            if self._experts[key].n_contacts > self.config.local_max_contacts:
                self._shrink(key)

    def _box(self, key: int, margin_m: float) -> tuple[FloatArray, FloatArray]:
        """The data box of expert `key` with this margin: voxel +- (blend + margin) per axis, (3,) and (3,)."""
        i = np.array([(key >> (2 * _KEY_BITS)) & _KEY_MASK, (key >> _KEY_BITS) & _KEY_MASK, key & _KEY_MASK])
        lo = (i - _KEY_OFFSET) * self.cell_m
        reach = self.blend_m + margin_m
        return lo - reach, lo + self.cell_m + reach

    def _filter_by_margin(self, P: FloatArray, groups: dict[int, IntArray]) -> dict[int, IntArray]:
        """Drop the rows outside an expert's own (possibly shrunk) data box, and for a thinned expert
        the rows whose cube it holds a contact of already."""
        out = {}
        for key, rows in groups.items():
            margin = self._margins.get(key, self.margin_m)
            if margin < self.margin_m:
                lo, hi = self._box(key, margin)
                inside = np.all((P[rows] >= lo) & (P[rows] <= hi), axis=1)
                rows = rows[inside]
            if key in self._thinned and rows.size:
                edge, held = self._thinned[key]
                rows = _first_per_cube(P, rows, edge, set(held))
            if rows.size:
                out[key] = rows
        return out

    def _shrink(self, key: int) -> None:
        """Halve an expert's margin (0 once below blend_m / 4), then thin it to one contact per cube of
        edge s (h / 8, doubling), rebuilding it from the contacts left in its box, until it holds at
        most local_max_contacts.

        Dense regions thus keep small experts (cost per touch and memory bounded by the cap) while
        sparse ones keep the full margin. O(n) scan of the contacts and one O(m^3) factorisation per round.
        """
        expert = self._experts[key]
        margin = self._margins.get(key, self.margin_m)
        positions, normals = self._P[: self._count], self._N[: self._count]
        edge = self._thinned[key][0] if key in self._thinned else 0.0
        cap = self.config.local_max_contacts
        widest = self.cell_m + 2.0 * (self.blend_m + self.margin_m)  # cubes this wide: <= 8 in any box
        while expert.n_contacts > cap and edge < widest:
            if margin > 0.0:
                margin = 0.0 if margin < 0.25 * self.blend_m else 0.5 * margin
            else:  # still over the cap with no margin left: one contact per cube, coarser each round
                edge = 2.0 * edge if edge else self.cell_m / 8.0
            lo, hi = self._box(key, margin)
            rows = np.flatnonzero(np.all((positions >= lo) & (positions <= hi), axis=1))
            if edge:
                held: set[tuple[int, int, int]] = set()
                rows = _first_per_cube(positions, rows, edge, held)
                self._thinned[key] = (edge, held)
            expert = GPIS(self.config, prior_centre_m=self._centre)
            expert.add_contacts(positions[rows], normals[rows])
        self._margins[key] = margin
        if expert.n_contacts == 0:  # none left in its box: it is no expert of E, the far field takes its weight
            del self._experts[key]
            self._pack.drop(key)
        else:
            self._experts[key] = expert
            self._pack.set(key, expert)

    def _coarsened_far(self, far: GPIS) -> tuple[GPIS, float, set[int]]:
        """The far field with its voxel edge doubled until it holds at most local_far_max_contacts: the
        first contact of each larger voxel (the first ever there is the first of its smaller voxel, so it
        is among ``far``'s contacts), rebuilt; with its edge and its voxels' keys. Changes nothing here."""
        positions, normals = far.positions_m, far.normals
        cell, rows = self._far_cell_m, np.arange(len(positions))
        while len(rows) > self.config.local_far_max_contacts:
            cell *= 2.0
            _, first = np.unique(_voxel_keys(positions, cell), return_index=True)
            rows = np.sort(first)
        rebuilt = GPIS(self.config, prior_centre_m=far.prior_centre_m)
        rebuilt.add_contacts(positions[rows], normals[rows])
        return rebuilt, cell, {int(k) for k in _voxel_keys(positions[rows], cell)}

    def _note_held(self, P: FloatArray, groups: dict[int, IntArray]) -> None:
        """Record the cubes of the contacts a thinned expert has just taken."""
        for key, rows in groups.items():
            if key in self._thinned:
                edge, held = self._thinned[key]
                held.update(_cubes(P[rows], edge))

    def _append(self, P: FloatArray, N: FloatArray) -> None:
        need = self._count + len(P)
        if need > len(self._P):
            cap = max(need, 2 * len(self._P), 64)
            grownP, grownN = np.zeros((cap, 3)), np.zeros((cap, 3))
            grownP[: self._count], grownN[: self._count] = self._P[: self._count], self._N[: self._count]
            self._P, self._N = grownP, grownN
        self._P[self._count : need], self._N[self._count : need] = P, N
        self._count = need

    def _memberships(self, P: FloatArray) -> dict[int, IntArray]:
        """Expert key -> rows of P within blend + margin of that expert's voxel on every axis."""
        h = self.cell_m
        reach = self.blend_m + self.margin_m  # voxel i holds [h i - reach, h (i + 1) + reach] per axis
        lo = np.ceil((P - reach) / h - 1.0 - 1e-12).astype(np.int64)
        hi = np.floor((P + reach) / h + 1e-12).astype(np.int64)
        keys: list[IntArray] = []
        rows: list[IntArray] = []
        for r in range(len(P)):
            ax = [np.arange(lo[r, k], hi[r, k] + 1) for k in range(3)]
            grid = np.stack(np.meshgrid(*ax, indexing="ij"), axis=-1).reshape(-1, 3)
            keys.append(_pack(grid))
            rows.append(np.full(len(grid), r, dtype=np.int64))
        k_all, r_all = np.concatenate(keys), np.concatenate(rows)
        order = np.argsort(k_all, kind="stable")
        k_all, r_all = k_all[order], r_all[order]
        starts = np.flatnonzero(np.r_[True, k_all[1:] != k_all[:-1]])
        ends = np.r_[starts[1:], len(k_all)]
        return {int(k_all[s]): r_all[s:e] for s, e in zip(starts, ends, strict=True)}

    def _far_members(self, P: FloatArray) -> IntArray:
        """Rows of P that are the first contact in their far-field voxel (this batch included)."""
        keys = _voxel_keys(P, self._far_cell_m)
        out, seen = [], set(self._far_cells)
        for r, k in enumerate(keys.tolist()):
            if k not in seen:
                seen.add(k)
                out.append(r)
        return np.asarray(out, dtype=np.int64)

    # --- queries -----------------------------------------------------------------------------------
    def mean(self, x: ArrayLike) -> FloatArray:
        """Blended posterior mean f(x) (m,) for x (m, 3)."""
        x = _points(x, "query points")
        f, _ = self._contract(x, gradient=False)
        return f

    def gradient(self, x: ArrayLike) -> FloatArray:
        """Gradient (m, 3) of the blended mean: grad m + sum_i w_i grad r_i + r_i grad w_i."""
        x = _points(x, "query points")
        _, g = self._contract(x, gradient=True)
        return g

    def variance(self, x: ArrayLike) -> FloatArray:
        """Mixture sum_i w_i var_i (m,) of the experts' posterior variances at x (m, 3), m^2.

        var_i = k(x, x) - |L_i^{-1} k_*|^2 (Eq. 6 of expert i): every expert's k_* columns are built in
        one compiled pass, each expert's block is solved in place (one BLAS call per expert), and
        the sums of squares come from a second compiled pass.
        """
        x = _points(x, "query points")
        prior = self.kernel.value_variance
        if self._count == 0 or len(x) == 0:
            return np.full(len(x), prior)
        pairs = self._pairs(x, gradient=False)
        P, _, starts, ends = self._pack.arrays()
        point = np.concatenate([pairs.point, pairs.far_point])
        slot = np.concatenate([pairs.slot, np.full(len(pairs.far_point), FAR_SLOT, dtype=np.int64)])
        weight = np.concatenate([pairs.weight, pairs.far_weight])
        order = np.argsort(slot, kind="stable")
        counts = np.bincount(slot, minlength=len(starts))
        col_starts = np.concatenate([[0], np.cumsum(counts)])
        rows = 4 * (ends - starts)
        offsets = np.concatenate([[0], np.cumsum(rows * counts)])
        blocks = np.empty(int(offsets[-1]))
        kind, p1, p2 = self._compiled_kernel()
        r_max = value_obs_blocks(x, point[order], col_starts, P, starts, ends, offsets, kind, p1, p2, blocks)
        self.kernel.check_distances(float(r_max))
        for s in np.flatnonzero(counts).tolist():
            block = blocks[offsets[s] : offsets[s + 1]].reshape((rows[s], counts[s]), order="F")
            expert = self._pack.experts[s]
            assert expert is not None  # a slot with query points has an expert
            expert.solve_factor_in_place(block)  # L_i V = k_*
        explained = np.empty(len(order))
        column_sums_of_squares(blocks, col_starts, rows, offsets, explained)
        var = np.maximum(prior - explained, 0.0)  # Eq. 6 per (point, expert), in slot order
        out = np.bincount(point[order], weights=weight[order] * var, minlength=len(x))
        return out.astype(np.float64, copy=False)  # float64 already (weighted); for the type checker

    def mean_and_variance(self, x: ArrayLike) -> tuple[FloatArray, FloatArray]:
        return self.mean(x), self.variance(x)

    def _contract(self, x: FloatArray, *, gradient: bool) -> tuple[FloatArray, FloatArray]:
        """Blended mean (m,) and, when asked, its gradient (m, 3) (zeros otherwise)."""
        centre = self._centre
        if self.config.prior == "sphere" and centre is None:
            raise EstimationError(
                "the sphere prior has no centre yet: pass prior_centre_m to LocalGPIS() or add a contact first"
            )
        f = prior_mean(self.config, x, centre)
        g = prior_gradient(self.config, x, centre) if gradient else np.zeros((len(x), 3))
        if self._count == 0 or len(x) == 0:
            return f, g
        pairs = self._pairs(x, gradient=gradient)
        P, A, starts, ends = self._pack.arrays()
        kind, p1, p2 = self._compiled_kernel()
        r_max = contract_pairs(
            x, pairs.point, pairs.slot, pairs.weight, pairs.weight_grad, starts, ends, P, A, kind, p1, p2,
            gradient, f, g,
        )  # fmt: skip
        self.kernel.check_distances(float(r_max))
        if self._far is not None and len(pairs.far_point):
            # The far field holds hundreds of contacts: the exact GP's vectorised contraction is faster
            # there. Each point appears once among the far pairs; r = f_far - m.
            idx, w = pairs.far_point, pairs.far_weight
            xi = x[idx]
            r = self._far.mean(xi) - prior_mean(self.config, xi, centre)
            f[idx] += w * r
            if gradient:
                grad_r = self._far.gradient(xi) - prior_gradient(self.config, xi, centre)
                g[idx] += w[:, None] * grad_r + r[:, None] * pairs.far_weight_grad
        return f, g

    def _compiled_kernel(self) -> tuple[int, float, float]:
        """(kind, p1, p2) of ``local_kernels`` for the configured kernel."""
        params = self.kernel.compiled()
        if params is None:  # pragma: no cover (every configurable kernel has compiled loops)
            raise EstimationError(f"LocalGPIS has no compiled contraction for the {self.kernel.name} kernel")
        return params

    def _pairs(self, x: FloatArray, *, gradient: bool) -> _Pairs:
        """Every (point, expert) with a non-zero weight at x (m, 3) (the expert's slot in the pack), and
        the points whose missing experts' weight goes to the far field."""
        table, table_slots = self._pack.table()
        point, pos, weight, weight_grad, far_w, far_g = blend_pairs(
            x, self.cell_m, self.blend_m, table, _KEY_BITS, gradient
        )
        need = np.flatnonzero(far_w > 1e-12) if self._far is not None else np.zeros(0, dtype=np.int64)
        # (round-off leaves ~1e-16 where experts cover everything)
        return _Pairs(
            point=point,
            slot=table_slots[pos],
            weight=weight,
            weight_grad=weight_grad,
            far_point=need,
            far_weight=far_w[need],
            far_weight_grad=far_g[need] if gradient else np.zeros((0, 3)),
        )


@dataclass(frozen=True)
class _Pairs:
    """(point, expert slot) pairs with blend weights (k,) and weight gradients (k, 3) (empty unless
    asked for), and the points (j,) that the far field weighs, with its weights and their gradients."""

    point: IntArray
    slot: IntArray
    weight: FloatArray
    weight_grad: FloatArray
    far_point: IntArray
    far_weight: FloatArray
    far_weight_grad: FloatArray


class AutoGPIS:
    """The exact GPIS up to config.auto_local_above_contacts contacts, then a LocalGPIS.

    The switch happens once, in the update that crosses the threshold: the local estimator is built
    from every contact so far (one batch per expert), and the exact GP is dropped with its factor.
    """

    def __init__(self, config: GPISConfig | None = None, *, prior_centre_m: ArrayLike | None = None) -> None:
        self.config = config if config is not None else GPISConfig()
        self._impl: GPIS | LocalGPIS = GPIS(self.config, prior_centre_m=prior_centre_m)
        self.kernel = self._impl.kernel

    @property
    def estimator(self) -> GPIS | LocalGPIS:
        """The estimator in use."""
        return self._impl

    @property
    def is_local(self) -> bool:
        return isinstance(self._impl, LocalGPIS)

    @property
    def n_contacts(self) -> int:
        return self._impl.n_contacts

    @property
    def positions_m(self) -> FloatArray:
        return self._impl.positions_m

    @property
    def normals(self) -> FloatArray:
        return self._impl.normals

    @property
    def prior_centre_m(self) -> FloatArray | None:
        return self._impl.prior_centre_m

    @property
    def supports_free_space(self) -> bool:
        """While exact; the local estimator takes no free space (its experts hold contacts only)."""
        return self._impl.supports_free_space

    def add_free_space(self, points_m: ArrayLike, distance_m: float) -> None:
        self._impl.add_free_space(points_m, distance_m)

    def drop_free_space(self) -> None:
        self._impl.drop_free_space()

    @property
    def supports_replaced_prior(self) -> bool:
        """While exact (see ``GPIS.replaced_prior``)."""
        return self._impl.supports_replaced_prior

    @property
    def prior_replaced(self) -> bool:
        return self._impl.prior_replaced

    def replaced_prior(self, prior: PriorMean) -> AbstractContextManager[None]:
        """The exact GP's (``GPIS.replaced_prior``); no contacts are taken within the block."""
        return self._impl.replaced_prior(prior)

    @property
    def factor_bytes(self) -> int:
        return self._impl.factor_bytes

    def add_contact(self, position_m: ArrayLike, normal: ArrayLike) -> None:
        self.add_contacts(*one_contact(position_m, normal))

    def add_contacts(self, positions_m: ArrayLike, normals: ArrayLike) -> None:
        P = _points(positions_m, "contact positions")
        if self.prior_replaced:  # the switch to the local estimator would skip GPIS.add_contacts's refusal
            raise EstimationError("contacts cannot be added while the prior is replaced (see replaced_prior)")
        impl = self._impl
        if isinstance(impl, LocalGPIS) or impl.n_contacts + len(P) <= self.config.auto_local_above_contacts:
            impl.add_contacts(P, normals)  # the normals are normalised once, there (the same bits as GPIS)
            return
        N = _unit_normals(normals, len(P))
        local = LocalGPIS(self.config, prior_centre_m=impl.prior_centre_m)
        if impl.n_contacts:
            local.add_contacts(impl.positions_m, impl.normals)
        local.add_contacts(P, N)
        self._impl = local

    def mean(self, x: ArrayLike) -> FloatArray:
        return self._impl.mean(x)

    def gradient(self, x: ArrayLike) -> FloatArray:
        return self._impl.gradient(x)

    def variance(self, x: ArrayLike) -> FloatArray:
        return self._impl.variance(x)

    def mean_and_variance(self, x: ArrayLike) -> tuple[FloatArray, FloatArray]:
        return self._impl.mean(x), self._impl.variance(x)


def make_estimator(
    config: GPISConfig | None = None, *, prior_centre_m: ArrayLike | None = None
) -> GPIS | LocalGPIS | AutoGPIS:
    """The estimator that config.estimator names: "exact" GPIS, "local" LocalGPIS or "auto" AutoGPIS."""
    cfg = config if config is not None else GPISConfig()
    if cfg.estimator == "exact":
        return GPIS(cfg, prior_centre_m=prior_centre_m)
    if cfg.estimator == "local":
        return LocalGPIS(cfg, prior_centre_m=prior_centre_m)
    return AutoGPIS(cfg, prior_centre_m=prior_centre_m)


def _cubes(points_m: FloatArray, edge: float) -> list[tuple[int, int, int]]:
    """The cubes of edge `edge` (m) that hold the points (n, 3), as integer index triples."""
    return [(i, j, k) for i, j, k in np.floor(points_m / edge).astype(np.int64).tolist()]


def _first_per_cube(P: FloatArray, rows: IntArray, edge: float, held: set[tuple[int, int, int]]) -> IntArray:
    """The rows of P (in order) whose cube of edge `edge` is not in `held` and not taken by an earlier row;
    `held` gains the cubes of the rows returned."""
    keep = []
    for r, cube in zip(rows.tolist(), _cubes(P[rows], edge), strict=True):
        if cube not in held:
            held.add(cube)
            keep.append(r)
    return np.asarray(keep, dtype=np.int64)
