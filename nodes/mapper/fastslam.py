"""FastSLAM with occupancy grids: a Rao-Blackwellised particle filter over finger joint angles.

Paper (000_*.txt, section III "Unknown finger pose"): K particles, each a finger-pose hypothesis
with its own occupancy grid; weight w_t^[k] = p(z_t | pose_t^[k], m_{t-1}^[k]); resample; each
particle updates its grid with the occupancy-grid algorithm at its own pose. One update here:

1. proposal: q^[k] = q_noisy + N(0, sigma^2 I), the sensor-noise model (sigma = 1.5 deg);
2. forward kinematics of all K poses at once, and the cells each pose touches (observation.py);
3. weight: log w^[k] += log p(z | q^[k], m^[k]) (``observation_log_likelihood``), normalised
   with log-sum-exp; N_eff = 1 / sum_k w_k^2;
4. map update: each particle's grid with its own pose (copy-on-write chunks, grid.py);
5. low-variance (systematic) resampling, only when N_eff < threshold * K; weights reset to 1/K.

The grids are updated (4) before resampling (5): resampling then shares the already-updated
chunks. In the opposite order, the n copies of one ancestor would each copy the same chunks
(copy-on-write) to write identical values into them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.special import logsumexp

from palpate.errors import ConfigError, EstimationError
from palpate.nodes.mapper.grid import L_FREE, L_OCC, LogOddsGrids, Observed, SparseMap, shown
from palpate.nodes.mapper.kinematics import KinematicChain
from palpate.nodes.mapper.observation import FreeVolume, observation_keys

FloatArray = NDArray[np.float64]


def normalise_log_weights(log_w: FloatArray) -> tuple[FloatArray, float]:
    """(log w - logsumexp(log w), N_eff) for log-weights (K,).

    Works when every exp(log w) underflows (log w = -1e6): only differences matter. Entries of -inf
    get weight 0; entries of +inf share all the weight; if every entry is -inf (or NaN) the weights
    are reset to uniform, 1/K each. N_eff = 1 / sum_k w_k^2, in [1, K].
    """
    lw = np.asarray(log_w, dtype=np.float64)
    K = lw.size
    if K == 0:
        raise ValueError("normalise_log_weights needs at least one particle's log-weight")
    infinite = lw == np.inf
    if infinite.any():  # infinitely more likely than the others: they share the weight
        return np.where(infinite, -math.log(int(infinite.sum())), -np.inf), float(infinite.sum())
    finite = np.isfinite(lw)
    if not finite.any():
        return np.full(K, -math.log(K)), float(K)
    # shift by the maximum first: the differences are exact (Sterbenz), so weights stay normalised
    # to 1e-15 even at log w = -1e6, where subtracting logsumexp directly would lose 1e-10
    lw = np.where(finite, lw - np.max(lw[finite]), -np.inf)
    lw = lw - logsumexp(lw[finite])
    w = np.exp(lw)
    return lw, float(1.0 / np.sum(w * w))


def systematic_resample(weights: FloatArray, rng: np.random.Generator) -> NDArray[np.intp]:
    """Low-variance resampling (Thrun et al., Probabilistic Robotics, table 4.4).

    One uniform draw u ~ U[0, 1/K); particle i is copied for each pointer u + k/K that falls in its
    slice of the cumulative weights. Each particle i gets floor(K w_i) or ceil(K w_i) copies.
    Returns ancestors (K,) in ascending order.
    """
    w = np.asarray(weights, dtype=np.float64)
    K = w.size
    if not (K and np.isfinite(w).all() and (w >= 0.0).all() and w.sum() > 0.0):
        raise ValueError(f"weights must be finite, non-negative and not all zero, got {shown(w)}")
    c = np.cumsum(w)
    c /= c[-1]
    pointers = (rng.random() + np.arange(K)) / K
    return np.minimum(np.searchsorted(c, pointers, side="right"), K - 1).astype(np.intp)


def cell_scores(prior_log_odds: NDArray[np.float32], occupied: bool, floor: float) -> NDArray[np.float32]:
    """Per cell log(max(p, floor) / 0.5) for a contact cell, log(max(1 - p, floor) / 0.5) for a free
    one, with p = 1 - 1 / (1 + exp(l)) the belief before the update (float32).

    Uses log(p) = -log(1 + exp(-l)) and log(1 - p) = -log(1 + exp(l)) (no overflow: |l| <= l_max).
    log(1 + exp(x)) rather than log1p: numpy's float32 log1p is not vectorised and 4x slower.
    """
    x = -prior_log_odds if occupied else prior_log_odds
    softplus = np.log(np.float32(1) + np.exp(x))
    return np.float32(math.log(2.0)) - np.minimum(softplus, np.float32(-math.log(floor)))


def observation_log_likelihood(
    observed: Observed, floor: float, free_weight: float = 1.0, free_reward: bool = True
) -> FloatArray:
    """log p(z | pose^[k], m^[k]) (K,), up to a constant shared by all particles.

    Cells are independent given the map (the occupancy-grid assumption). With p the belief of a
    cell before the update, a contact cell scores log(max(p, floor) / 0.5) and a free cell
    log(max(1 - p, floor) / 0.5): each term is the likelihood ratio of the observation against an
    uninformed map (p = 0.5). Unobserved cells therefore score exactly 0, so a pose that happens to
    cover more cells is not penalised for it; the floor bounds the penalty of one surprising cell by
    log(2 floor) (-3.9 for the default floor 0.01), so one cell cannot zero a particle. Each distinct cell
    counts once (``Observed.counted_*``). ``free_weight`` scales the free cells' terms.

    ``free_reward`` False: a free cell scores min(0, log(max(1 - p, floor) / 0.5)), a penalty where
    the finger's volume overlaps cells the map believes occupied and nothing where it lies in known
    free space. With the reward (True, up to log 2 per cell), hundreds of free cells outvote the few
    contact cells and favour the poses whose finger overlaps most of the space already swept, a bias
    unrelated to the true pose: on the Rubik's cube scene of the graph FastSLAM's map then came out
    worse than dead reckoning's, and without it clearly better (docs/slam.md).
    """
    if observed.counted_free is None or observed.counted_occ is None:
        raise EstimationError("the particle weights need LogOddsGrids.observe(..., count=True)")
    s_free = cell_scores(observed.prior_free, False, floor)
    if not free_reward:
        np.minimum(s_free, np.float32(0), out=s_free)
    s_occ = cell_scores(observed.prior_occ, True, floor)
    s_free *= observed.counted_free
    s_occ *= observed.counted_occ
    ll_free = s_free.sum(axis=1).astype(np.float64)  # float32 pairwise sums: ~1e-6 relative error
    ll_occ = s_occ.sum(axis=1).astype(np.float64)
    return np.asarray(free_weight * ll_free + ll_occ)


@dataclass(frozen=True)
class StepStats:
    """What one update did: effective sample size before resampling, whether it resampled, and
    how many free-volume and contact points fell outside the grid (summed over particles)."""

    n_eff: float
    resampled: bool
    free_points_outside: int
    contacts_outside: int


class FastSlam:
    """K particles, each joint angles q^[k] (J,) and its own log-odds grid (shared chunks)."""

    def __init__(
        self,
        *,
        chain: KinematicChain,
        grids: LogOddsGrids,
        free_volume: FreeVolume,
        sigma_rad: float | FloatArray,
        rng: np.random.Generator,
        resample_threshold: float = 0.5,
        likelihood_floor: float = 0.01,
        free_weight: float = 1.0,
        free_reward: bool = True,
        l_occ: float = L_OCC,
        l_free: float = L_FREE,
        free_depth_cells: tuple[NDArray[np.float32], ...] = (),
    ) -> None:
        sigma = np.broadcast_to(np.asarray(sigma_rad, dtype=np.float64), (chain.n_joints,))
        if not (np.all(sigma >= 0) and np.all(np.isfinite(sigma))):
            raise ConfigError(f"sigma must be finite and >= 0, got {sigma_rad!r} rad")
        if not 0.0 <= resample_threshold <= 1.0:
            raise ConfigError(f"resample_threshold must be in [0, 1], got {resample_threshold!r}")
        if not 0.0 < likelihood_floor < 0.5:
            raise ConfigError(f"likelihood_floor must be in (0, 0.5), got {likelihood_floor!r}")
        self.chain = chain
        self.grids = grids
        self.free_volume = free_volume
        self._free_h = free_volume.homogeneous()
        self._free_depth = free_depth_cells  # given: a free point clears only a cell wholly in the finger
        self.sigma_rad = sigma.copy()  # per joint (J,)
        self.rng = rng
        self.resample_threshold = float(resample_threshold)
        self.likelihood_floor = float(likelihood_floor)
        self.free_weight = float(free_weight)
        self.free_reward = bool(free_reward)
        self.l_occ = float(l_occ)
        self.l_free = float(l_free)
        K = grids.n_maps
        self.n_particles = K
        self.log_weights = np.full(K, -math.log(K))
        self.q = np.zeros((K, chain.n_joints))
        self.n_eff = float(K)
        self.best = 0
        self.n_resamples = 0

    @property
    def weights(self) -> FloatArray:
        """Normalised weights (K,)."""
        return np.asarray(np.exp(self.log_weights))

    def update(self, q_noisy: FloatArray, contact_links: NDArray[np.integer], contact_local_m: FloatArray) -> StepStats:
        """One filter step for the joint reading q_noisy (J,) rad and contacts (n,), (n, 3) m."""
        K, J = self.n_particles, self.chain.n_joints
        # 1. proposal: q^[k] = q_noisy + N(0, sigma^2)
        q = np.asarray(q_noisy, dtype=np.float64)[None, :] + self.sigma_rad * self.rng.standard_normal((K, J))
        # 2. forward kinematics and cells, all particles at once
        rots, pos = self.chain.forward(q)
        free, occ = observation_keys(
            self.grids, rots, pos, self._free_h, contact_links, contact_local_m, self._free_depth
        )
        # 4. (before 3 uses the priors) each particle updates its own map at its own pose
        observed = self.grids.observe(free, occ, l_free=self.l_free, l_occ=self.l_occ, count=True)
        # 3. w^[k] = p(z | q^[k], m_{t-1}^[k]), accumulated in log space, normalised by log-sum-exp
        ll = observation_log_likelihood(observed, self.likelihood_floor, self.free_weight, self.free_reward)
        self.log_weights, self.n_eff = normalise_log_weights(self.log_weights + ll)
        self.q = q
        self.best = int(np.argmax(self.log_weights))
        # 5. low-variance resampling only when the effective sample size drops
        resampled = K > 1 and self.n_eff < self.resample_threshold * K
        if resampled:
            ancestors = systematic_resample(self.weights, self.rng)
            self.grids.resample(ancestors)
            self.q = self.q[ancestors]
            # the best particle (K w >= 1) has at least one copy; ancestors are sorted
            self.best = min(int(np.searchsorted(ancestors, self.best)), K - 1)
            self.log_weights = np.full(K, -math.log(K))
            self.n_resamples += 1
        return StepStats(
            n_eff=self.n_eff, resampled=resampled, free_points_outside=free.n_outside, contacts_outside=occ.n_outside
        )

    def mean_q(self) -> FloatArray:
        """Weighted mean joint angles (J,) rad (angles stay within a few sigma: no wrap-around)."""
        return np.asarray(self.weights @ self.q)

    def best_q(self) -> FloatArray:
        """Joint angles (J,) of the highest-weight particle."""
        return np.asarray(self.q[self.best].copy())

    def best_map(self) -> SparseMap:
        return self.grids.to_sparse(self.best)

    def weighted_map(self) -> SparseMap:
        return self.grids.weighted(self.weights)
