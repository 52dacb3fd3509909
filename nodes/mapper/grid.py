"""Sparse 3D log-odds occupancy grids, many maps sharing copy-on-write chunks.

The paper (000_*.txt, section III "Known finger pose") keeps one log-odds value per cell:

    l_t = l_{t-1} + log(p(occ | z_t) / (1 - p(occ | z_t))) - l_0,      l_0 = log(0.5 / 0.5) = 0

with log(0.9/0.1) for a cell at a contact and log(0.1/0.9) for a cell the finger occupies without
contact, and recovers the belief as bel_t(occ) = 1 - 1 / (1 + exp(l_t)).

Storage. The region is cut into cubic chunks of ``chunk_edge**3`` cells. All chunks of all maps live
in one pool (``(n_slots, chunk_edge**3)`` float32); each map holds a table ``chunk id -> pool slot``
(-1: never written, every cell at the prior l_0 = 0). Memory therefore grows with the touched cells,
not with the region: a 10^7-cell grid costs a 78 kB table per map plus 2 kB per touched chunk.

Copy-on-write (as gmapping shares map patches between particles): resampling copies the tables
only (int32 per chunk), and a slot is shared by every map whose table points at it (``refcount``).
A map copies a chunk only when it writes to a chunk that another map also holds; when every holder
of a shared chunk writes in the same call, the first keeps the original and the others copy it.

Clamping. Log-odds are clamped to [l_min, l_max] (default +-10, i.e. belief in
[4.5e-5, 1 - 4.5e-5]) after each update, so that a cell hit a million times stays finite, and 5
contrary observations (5 * log 9 = 11 > 10) are enough to move a saturated cell back across 0.5:
the map can change its mind.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import expit

from palpate.errors import ConfigError

FloatArray = NDArray[np.floating]
IntArray = NDArray[np.integer]

#: Paper values: log(0.9 / 0.1) for a contact cell, log(0.1 / 0.9) for a free cell.
L_OCC = math.log(0.9 / 0.1)
L_FREE = math.log(0.1 / 0.9)
#: ``weighted`` takes particle weights that sum to 1 within this (normalised weights are within 1e-15).
WEIGHT_SUM_TOLERANCE = 1e-6


def shown(values: ArrayLike, limit: int = 5) -> str:
    """A few of the values, for an error message: ``[0.1, nan, 0.3, ...] (300 values, sum nan)``."""
    v = np.asarray(values, dtype=np.float64).ravel()
    if v.size <= limit:
        return str(v.tolist())
    return f"{str(v[:limit].tolist())[:-1]}, ...] ({v.size} values, sum {float(v.sum()):.6g})"


def belief(log_odds: FloatArray) -> NDArray[np.float64]:
    """Occupancy belief bel = 1 - 1 / (1 + exp(l)) (paper, section III), as the logistic function.

    ``expit`` never overflows: l = +-1e30 gives exactly 1 and 0, never NaN.
    """
    return np.asarray(expit(np.asarray(log_odds, dtype=np.float64)), dtype=np.float64)


def log_odds_of(p: FloatArray, eps: float = 1e-12) -> NDArray[np.float64]:
    """l = log(p / (1 - p)), with p clipped to [eps, 1 - eps] so that 0 and 1 stay finite."""
    q = np.clip(np.asarray(p, dtype=np.float64), eps, 1.0 - eps)
    return np.asarray(np.log(q) - np.log1p(-q), dtype=np.float64)


def update_log_odds(
    prior: NDArray[np.float32], delta: NDArray[np.float32] | float, l_min: float, l_max: float
) -> NDArray[np.float32]:
    """l_t = clamp(l_{t-1} + log(p(occ | z) / (1 - p(occ | z))) - l_0, l_min, l_max), l_0 = 0 (float32)."""
    new = np.asarray(prior, dtype=np.float32) + np.float32(delta)
    np.maximum(new, np.float32(l_min), out=new)  # (cheaper than np.clip, which re-checks dtypes)
    np.minimum(new, np.float32(l_max), out=new)
    return new


#: Most cells a grid may have: its flat cell indices are int64.
MAX_CELLS = 2.0**62
#: Most cells along one axis: a cell's coordinates are int32 (``LogOddsGrids.cell_keys``).
MAX_CELLS_PER_AXIS = 2**31 - 1


@dataclass(frozen=True, kw_only=True)
class GridSpec:
    """Geometry of a grid: cell (i, j, k) covers origin_m + [i, i+1) * resolution_m (per axis).

    origin_m: (3,) lower corner of cell (0, 0, 0), metres; resolution_m: cell edge, metres;
    shape: (3,) number of cells per axis. Flat index = (i * ny + j) * nz + k (C order).
    """

    origin_m: tuple[float, float, float]
    resolution_m: float
    shape: tuple[int, int, int]

    def __post_init__(self) -> None:
        if not (math.isfinite(self.resolution_m) and self.resolution_m > 0):
            raise ConfigError(f"resolution_m must be a positive number, got {self.resolution_m!r}")
        if len(self.shape) != 3 or not all(isinstance(n, (int, np.integer)) and n >= 1 for n in self.shape):
            raise ConfigError(f"shape must be 3 positive integer cell counts, got {self.shape!r}")
        if max(self.shape) > MAX_CELLS_PER_AXIS:  # a cell's coordinates are int32 (``cell_keys``)
            raise ConfigError(f"shape {self.shape!r} has more than {MAX_CELLS_PER_AXIS:,} cells along an axis")
        if len(self.origin_m) != 3 or not all(math.isfinite(x) for x in self.origin_m):
            raise ConfigError(f"origin_m must be 3 finite numbers, got {self.origin_m!r}")

    @classmethod
    def from_bounds(
        cls, min_m: tuple[float, float, float], max_m: tuple[float, float, float], resolution_m: float
    ) -> GridSpec:
        """The grid of cells of edge resolution_m that covers the box [min_m, max_m] (metres)."""
        lo = np.asarray(min_m, dtype=np.float64)
        hi = np.asarray(max_m, dtype=np.float64)
        if lo.shape != (3,) or hi.shape != (3,) or not np.all(hi > lo):
            raise ConfigError(f"region max {max_m!r} must exceed region min {min_m!r} on every axis")
        if not (math.isfinite(resolution_m) and resolution_m > 0):
            raise ConfigError(f"resolution_m must be a positive number, got {resolution_m!r}")
        with np.errstate(over="ignore"):
            cells = np.maximum(1.0, np.ceil((hi - lo) / resolution_m - 1e-9))
            total = float(np.prod(cells))
        if not (total < MAX_CELLS and float(cells.max()) <= MAX_CELLS_PER_AXIS):  # also inf and NaN
            raise ConfigError(
                f"resolution_m {resolution_m!r} is too fine for the region {min_m!r} to {max_m!r}: "
                f"{' x '.join(f'{c:.3g}' for c in cells)} cells, more than {MAX_CELLS:.3g} or more than "
                f"{MAX_CELLS_PER_AXIS:.3g} along an axis (flat cell indices are 64-bit, a cell's coordinates 32-bit); "
                "use a coarser resolution or a smaller region"
            )
        n = cells.astype(int)
        return cls(
            origin_m=(float(lo[0]), float(lo[1]), float(lo[2])),
            resolution_m=float(resolution_m),
            shape=(int(n[0]), int(n[1]), int(n[2])),
        )

    @property
    def n_cells(self) -> int:
        return int(np.prod(np.asarray(self.shape, dtype=np.int64)))

    def centers(self, flat: IntArray) -> NDArray[np.float64]:
        """Cell centres (n, 3) in metres of flat indices (n,)."""
        ijk = np.stack(np.unravel_index(np.asarray(flat, dtype=np.int64), self.shape), axis=-1)
        return np.asarray(np.asarray(self.origin_m) + (ijk + 0.5) * self.resolution_m, dtype=np.float64)

    def flat_of_points(self, points_m: FloatArray) -> tuple[NDArray[np.bool_], NDArray[np.int64]]:
        """(inside (n,), flat (m,)) for points (n, 3): the flat index of each point inside the grid."""
        f = (np.asarray(points_m, dtype=np.float64) - np.asarray(self.origin_m)) / self.resolution_m
        inside = np.all((f >= 0) & (f < np.asarray(self.shape)), axis=-1)
        ijk = np.floor(f[inside]).astype(np.int64)
        return inside, np.ravel_multi_index(ijk.T, self.shape).astype(np.int64)


@dataclass(frozen=True)
class SparseMap:
    """A map as its touched cells: flat indices (n,) int64 ascending and log-odds (n,) float32.

    Cells not listed hold the prior l_0 = 0 (belief 0.5).
    """

    spec: GridSpec
    flat: NDArray[np.int64]
    log_odds: NDArray[np.float32]

    def dense(self) -> NDArray[np.float32]:
        """Log-odds as a dense (nx, ny, nz) float32 array (small grids only)."""
        out = np.zeros(self.spec.n_cells, dtype=np.float32)
        out[self.flat] = self.log_odds
        return out.reshape(self.spec.shape)

    def belief(self) -> NDArray[np.float64]:
        """Belief (n,) of the listed cells."""
        return belief(self.log_odds.astype(np.float64))


@dataclass(frozen=True)
class CellKeys:
    """Cells of K poses in the dense (K, P) layout used by ``observe``: row k belongs to map k.

    key (K, P): map * (n_chunks + 1) + chunk id; offset (K, P): cell within the chunk; valid (K, P)
    bool (None: all valid); n_outside: number of points outside the region (invalid entries, which
    point at a per-grid scratch chunk and change no map; ``observation_keys`` makes other points invalid
    too, and leaves them out of this count).
    """

    key: NDArray[np.integer]
    offset: NDArray[np.integer]
    valid: NDArray[np.bool_] | None
    n_outside: int


@dataclass(frozen=True)
class Observed:
    """Log-odds before one observation, and which entries count, in the (K, P) layout of its keys.

    prior_free (K, Pf), prior_occ (K, n): float32 log-odds before the update. counted_free,
    counted_occ (bool, same shapes): True for exactly one entry per distinct (map, cell) inside the
    region, the occupied entry winning over a free one in the same cell; None unless requested.
    """

    prior_free: NDArray[np.float32]
    prior_occ: NDArray[np.float32]
    counted_free: NDArray[np.bool_] | None
    counted_occ: NDArray[np.bool_] | None


class LogOddsGrids:
    """``n_maps`` sparse log-odds grids over one GridSpec, storing chunks copy-on-write.

    Hot path: ``cell_keys`` turns cell coordinates of K poses into (map, chunk, offset) keys and
    ``observe`` applies one observation to all K maps at once. ``locate``, ``read_flat`` and
    ``update_flat`` are the plain per-cell interface.
    """

    def __init__(
        self,
        spec: GridSpec,
        n_maps: int,
        *,
        chunk_edge: int = 8,
        l_min: float = -10.0,
        l_max: float = 10.0,
        initial_slots: int = 64,
    ) -> None:
        if n_maps < 1:
            raise ConfigError(f"n_maps must be at least 1, got {n_maps!r}")
        if chunk_edge < 1 or chunk_edge & (chunk_edge - 1):
            raise ConfigError(f"chunk_edge must be a power of two, got {chunk_edge!r}")
        if not (l_min < 0 < l_max and math.isfinite(l_min) and math.isfinite(l_max)):
            raise ConfigError(f"need finite l_min < 0 < l_max, got l_min={l_min!r}, l_max={l_max!r}")
        self.spec = spec
        self.n_maps = int(n_maps)
        self.chunk_edge = int(chunk_edge)
        self.l_min = float(l_min)
        self.l_max = float(l_max)
        self._shift = self.chunk_edge.bit_length() - 1
        self.cells_per_chunk = self.chunk_edge**3
        self.chunk_shape = tuple(-(-n // self.chunk_edge) for n in spec.shape)
        self.n_chunks = int(np.prod(self.chunk_shape))
        self._row = self.n_chunks + 1  # table columns: the chunks, then the scratch chunk
        n_keys = self.n_maps * self._row
        self._key_dtype: type[np.integer] = np.int32 if n_keys < 2**31 else np.int64
        # slot 0 is the scratch chunk every map's last column points at (never exported or copied)
        self._table = np.full((self.n_maps, self._row), -1, dtype=np.int32)
        self._table[:, self.n_chunks] = 0
        self._mark = np.zeros(n_keys, dtype=np.bool_)
        cap = max(2, int(initial_slots))
        self._pool = np.zeros((cap, self.cells_per_chunk), dtype=np.float32)
        self._stamp = np.zeros(cap * self.cells_per_chunk, dtype=np.int32)
        self._refcount = np.zeros(cap, dtype=np.int32)
        self._refcount[0] = self.n_maps
        self._n_used = 1  # slots ever handed out; those below it are live or on the free list
        self._free = np.zeros(0, dtype=np.int64)
        #: Chunks copied because a map wrote to a chunk it shared (copy-on-write), since creation.
        self.chunk_copies = 0

    # --- geometry --------------------------------------------------------------------------------
    def cell_keys(self, f: NDArray[np.floating]) -> CellKeys:
        """Keys of cell coordinates f (K, 3, P) = (x - origin_m) / resolution_m of K poses' points.

        Row k of the result addresses map k. NaN or out-of-region points become invalid entries.
        """
        K, _, _P = f.shape
        shape = np.asarray(self.spec.shape)
        lo = f.min(axis=(0, 2)) if f.size else np.zeros(3)
        hi = f.max(axis=(0, 2)) if f.size else np.zeros(3)
        valid: NDArray[np.bool_] | None = None
        if not (np.all(lo >= 0) and np.all(hi < shape)):  # NaN fails both tests
            n = shape.astype(f.dtype)
            valid = f[:, 0] >= 0
            for a in range(3):
                if a:
                    valid &= f[:, a] >= 0
                valid &= f[:, a] < n[a]
            # invalid points are redirected to the scratch chunk below; clamp so the cast is defined
            # (fmax / fmin return the number when the other operand is NaN)
            f = np.fmax(f, f.dtype.type(0))
            np.fmin(f, (n - 1)[None, :, None], out=f)
        ijk = f.astype(np.int32)  # non-negative: truncation is floor
        c = ijk >> self._shift
        ijk &= self.chunk_edge - 1
        ncy, ncz = self.chunk_shape[1], self.chunk_shape[2]
        e = self.chunk_edge
        chunk = c[:, 0] * ncy
        chunk += c[:, 1]
        chunk *= ncz
        chunk += c[:, 2]
        offset = ijk[:, 0] * e
        offset += ijk[:, 1]
        offset *= e
        offset += ijk[:, 2]
        row = (np.arange(K, dtype=self._key_dtype) * self._row)[:, None]
        key: NDArray[np.integer] = chunk.astype(self._key_dtype, copy=False) + row
        n_out = 0
        if valid is not None:
            key = np.where(valid, key, row + self.n_chunks)
            offset *= valid
            n_out = int(valid.size - np.count_nonzero(valid))
        return CellKeys(key=key, offset=offset, valid=valid, n_outside=n_out)

    def keys_of_flat(self, map_index: int, flat: IntArray) -> CellKeys:
        """Keys (1, n) of flat cells (n,) in one map."""
        self._check_map(map_index)
        chunk, offset = self.chunk_offset_of_flat(self._flat_cells(flat))
        key = (chunk + map_index * self._row).astype(self._key_dtype)[None, :]
        return CellKeys(key=key, offset=offset.astype(np.int32)[None, :], valid=None, n_outside=0)

    def locate(self, points_m: FloatArray) -> tuple[NDArray[np.bool_], NDArray[np.intp], NDArray[np.intp]]:
        """(inside (n,), chunk (m,), offset (m,)) of points (n, 3); m = inside.sum().

        Points outside the region (and NaN) are dropped; ``inside`` says which were kept.
        """
        inside, flat = self.spec.flat_of_points(points_m)
        chunk, offset = self.chunk_offset_of_flat(flat)
        return inside, chunk, offset

    def chunk_offset_of_flat(self, flat: IntArray) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """(chunk (n,), offset (n,)) of flat cell indices (n,)."""
        ijk = np.stack(np.unravel_index(np.asarray(flat, dtype=np.intp), self.spec.shape), axis=-1)
        c = ijk >> self._shift
        o = ijk & (self.chunk_edge - 1)
        e = self.chunk_edge
        chunk = np.ravel_multi_index(c.T, self.chunk_shape)
        return chunk.astype(np.intp), ((o[:, 0] * e + o[:, 1]) * e + o[:, 2]).astype(np.intp)

    def flat_of_chunk_offset(self, chunk: IntArray, offset: IntArray) -> NDArray[np.int64]:
        """Flat cell indices (n,) of (chunk, offset) pairs (n,); -1 where the cell is outside the grid."""
        c = np.stack(np.unravel_index(np.asarray(chunk, dtype=np.intp), self.chunk_shape), axis=-1)
        e = self.chunk_edge
        o = np.stack(np.unravel_index(np.asarray(offset, dtype=np.intp), (e, e, e)), axis=-1)
        ijk = c * e + o
        ok = np.all(ijk < np.asarray(self.spec.shape), axis=-1)
        flat = np.full(len(ijk), -1, dtype=np.int64)
        flat[ok] = np.ravel_multi_index(ijk[ok].T, self.spec.shape)
        return flat

    # --- slot management -------------------------------------------------------------------------
    def _alloc(self, n: int) -> NDArray[np.intp]:
        """n pool slots (contents undefined), from the free list first, growing the pool if needed."""
        take = min(n, len(self._free))
        reused = self._free[len(self._free) - take :]
        self._free = self._free[: len(self._free) - take]
        fresh_n = n - take
        if self._n_used + fresh_n > len(self._pool):
            self._grow(self._n_used + fresh_n)
        fresh = np.arange(self._n_used, self._n_used + fresh_n, dtype=np.intp)
        self._n_used += fresh_n
        return np.concatenate([reused.astype(np.intp), fresh])

    def _grow(self, min_slots: int) -> None:
        cap = max(min_slots, 2 * len(self._pool))
        pool = np.zeros((cap, self.cells_per_chunk), dtype=np.float32)
        pool[: self._n_used] = self._pool[: self._n_used]
        self._pool = pool
        self._stamp = np.zeros(cap * self.cells_per_chunk, dtype=np.int32)
        refcount = np.zeros(cap, dtype=np.int32)
        refcount[: len(self._refcount)] = self._refcount
        self._refcount = refcount

    def _ensure_writable(self, keys: NDArray[np.integer]) -> None:
        """Give every (map, chunk) key its own pool slot: allocate, or copy a shared chunk."""
        self._mark[keys] = True
        pairs = np.flatnonzero(self._mark)  # distinct keys without sorting (the table is small)
        self._mark[pairs] = False
        pairs = pairs[pairs % self._row != self.n_chunks]  # the scratch chunk is never copied
        table = self._table.reshape(-1)
        slots = table[pairs].astype(np.intp)
        new = slots < 0
        if new.any():
            s = self._alloc(int(new.sum()))
            self._pool[s] = 0.0
            self._refcount[s] = 1
            table[pairs[new]] = s
        shared = np.zeros_like(new)
        shared[~new] = self._refcount[slots[~new]] > 1
        if shared.any():
            old = slots[shared]
            targets = pairs[shared]
            uniq, first, writers = np.unique(old, return_index=True, return_counts=True)
            copy = np.ones(len(old), dtype=np.bool_)
            # if every holder writes now, the first writer keeps the original slot
            copy[first[writers == self._refcount[uniq]]] = False
            old_c = old[copy]
            s = self._alloc(len(old_c))
            self._pool[s] = self._pool[old_c]
            self._refcount[s] = 1
            np.subtract.at(self._refcount, old_c, 1)
            table[targets[copy]] = s
            self.chunk_copies += len(old_c)

    # --- reading and writing ---------------------------------------------------------------------
    def read_flat(self, map_index: int, flat: IntArray) -> NDArray[np.float32]:
        """Log-odds (n,) of flat cells (n,) in one map; 0 (the prior) for cells never written."""
        self._check_map(map_index)
        chunk, offset = self.chunk_offset_of_flat(self._flat_cells(flat))
        slots = self._table[map_index, chunk]
        out = np.zeros(len(slots), dtype=np.float32)
        ok = slots >= 0
        out[ok] = self._pool.reshape(-1)[slots[ok].astype(np.intp) * self.cells_per_chunk + offset[ok]]
        return out

    def observe(
        self,
        free: CellKeys,
        occ: CellKeys,
        l_free: float = L_FREE,
        l_occ: float = L_OCC,
        count: bool = True,
    ) -> Observed:
        """Apply one observation to many maps: l <- clamp(l + l_free) or clamp(l + l_occ) (paper III).

        free: cells the finger occupies without contact; occ: contact cells. Each distinct
        (map, cell) is updated ONCE however many points fell into it: every duplicate reads the same
        prior and writes the same value. A cell both free and occupied takes the occupied update
        (the contact lies on the finger's surface, inside the finger's cell). ``count``: also mark
        one entry per distinct (map, cell) for the particle weights.
        """
        fk, ok_ = free.key.reshape(-1), occ.key.reshape(-1)
        self._ensure_writable(np.concatenate([fk, ok_]))
        table = self._table.reshape(-1)
        c = self.cells_per_chunk
        addr_f = table[fk].astype(np.intp)
        addr_f *= c
        addr_f += free.offset.reshape(-1)
        addr_o = table[ok_].astype(np.intp)
        addr_o *= c
        addr_o += occ.offset.reshape(-1)
        pool = self._pool.reshape(-1)
        prior_f = pool[addr_f]
        prior_o = pool[addr_o]
        counted_f = counted_o = None
        if count:
            # one entry per address: the last stamp written wins, whichever it is; occupied cells
            # are stamped after the free ones, so a cell both free and occupied counts as occupied
            n_f = len(addr_f)
            idx = np.arange(n_f + len(addr_o), dtype=np.int32)
            self._stamp[addr_f] = idx[:n_f]
            self._stamp[addr_o] = idx[n_f:]
            counted_f = (self._stamp[addr_f] == idx[:n_f]).reshape(free.key.shape)
            counted_o = (self._stamp[addr_o] == idx[n_f:]).reshape(occ.key.shape)
            if free.valid is not None:
                counted_f &= free.valid
            if occ.valid is not None:
                counted_o &= occ.valid
        # free first, then occupied, so that the occupied value is the one left in a cell that is both
        pool[addr_f] = update_log_odds(prior_f, l_free, self.l_min, self.l_max)
        pool[addr_o] = update_log_odds(prior_o, l_occ, self.l_min, self.l_max)
        return Observed(
            prior_free=prior_f.reshape(free.key.shape),
            prior_occ=prior_o.reshape(occ.key.shape),
            counted_free=counted_f,
            counted_occ=counted_o,
        )

    def update_flat(self, map_index: int, free_flat: IntArray, occ_flat: IntArray) -> Observed:
        """``observe`` on flat cell indices of one map (the plain interface for tools and tests)."""
        return self.observe(self.keys_of_flat(map_index, free_flat), self.keys_of_flat(map_index, occ_flat))

    # --- particles -------------------------------------------------------------------------------
    def resample(self, ancestors: IntArray) -> None:
        """Map k becomes a copy of map ancestors[k] (n_maps,), sharing chunks: no chunk data moves."""
        anc = np.asarray(ancestors, dtype=np.intp)
        if anc.shape != (self.n_maps,):
            raise ConfigError(f"ancestors must have shape ({self.n_maps},), got {anc.shape}")
        if len(anc) and not (anc.min() >= 0 and anc.max() < self.n_maps):
            raise ValueError(f"ancestors must be map indices 0..{self.n_maps - 1}, got {shown(anc)}")
        self._table = self._table[anc]
        live = self._table[self._table >= 0]
        self._refcount = np.bincount(live, minlength=len(self._pool)).astype(np.int32)
        self._free = np.flatnonzero(self._refcount[: self._n_used] == 0).astype(np.int64)

    def shares_chunk_data(self, a: int, b: int) -> int:
        """Number of chunks maps a and b hold in the same pool slot (a diagnostic for tests)."""
        ta, tb = self._table[a, : self.n_chunks], self._table[b, : self.n_chunks]
        return int(np.sum((ta >= 0) & (ta == tb)))

    # --- export ----------------------------------------------------------------------------------
    def to_sparse(self, map_index: int) -> SparseMap:
        """Map ``map_index`` as its cells with log-odds != 0, flat indices ascending."""
        self._check_map(map_index)
        row = self._table[map_index, : self.n_chunks]
        chunks = np.flatnonzero(row >= 0)
        data = self._pool[row[chunks]]
        ci, oi = np.nonzero(data)
        return self._sparse(chunks[ci], oi, data[ci, oi])

    def _sparse(self, chunk: NDArray[np.intp], offset: NDArray[np.intp], values: FloatArray) -> SparseMap:
        flat = self.flat_of_chunk_offset(chunk, offset)
        ok = flat >= 0
        order = np.argsort(flat[ok], kind="stable")
        return SparseMap(spec=self.spec, flat=flat[ok][order], log_odds=values[ok][order].astype(np.float32))

    def to_dense(self, map_index: int) -> NDArray[np.float32]:
        """Log-odds of map ``map_index`` as a dense (nx, ny, nz) float32 array (small grids only)."""
        return self.to_sparse(map_index).dense()

    def weighted(self, weights: FloatArray) -> SparseMap:
        """The weighted map: per cell, log-odds of sum_k w_k bel_k (weights (n_maps,), sum 1).

        Covers the cells any map touched; a map that did not touch a cell counts with bel = 0.5.
        Works per pool slot, not per map: a chunk shared by many maps is read once, with the
        summed weight of its holders (a slot always sits at the same chunk id in every table).
        """
        w = np.asarray(weights, dtype=np.float64)
        if w.shape != (self.n_maps,) or not (np.isfinite(w).all() and (w >= 0.0).all()):
            raise ValueError(f"weights must be {self.n_maps} finite non-negative numbers, got {shown(w)}")
        if abs(w.sum() - 1.0) > WEIGHT_SUM_TOLERANCE:
            raise ValueError(f"weights must sum to 1, got {float(w.sum())!r}")
        table = self._table[:, : self.n_chunks]
        k_idx, c_idx = np.nonzero(table >= 0)
        slots = table[k_idx, c_idx].astype(np.intp)
        slot_w = np.bincount(slots, weights=w[k_idx], minlength=len(self._pool))
        live, first = np.unique(slots, return_index=True)
        chunks, row = np.unique(c_idx[first], return_inverse=True)  # chunk of each live slot
        data = self._pool[live]  # (n_live, C)
        bel = np.zeros((len(chunks), self.cells_per_chunk))
        np.add.at(bel, row, slot_w[live, None] * belief(data))
        held_w = np.bincount(row, weights=slot_w[live], minlength=len(chunks))
        bel += (1.0 - held_w)[:, None] * 0.5  # maps without the chunk: prior belief 0.5
        touched = np.zeros(bel.shape, dtype=np.bool_)
        np.logical_or.at(touched, row, data != 0)
        ci, oi = np.nonzero(touched)
        return self._sparse(chunks[ci], oi, log_odds_of(bel[ci, oi]))

    # --- checks of the plain interface -----------------------------------------------------------
    def _check_map(self, map_index: int) -> None:
        if not (isinstance(map_index, int | np.integer) and 0 <= map_index < self.n_maps):
            raise ValueError(f"map_index must be 0..{self.n_maps - 1}, got {map_index!r}")

    def _flat_cells(self, flat: IntArray) -> NDArray[np.int64]:
        cells = np.asarray(flat).reshape(-1)
        if cells.size and not np.issubdtype(cells.dtype, np.integer):
            raise ValueError(f"flat cell indices must be integers, got {cells.dtype}")
        cells64: NDArray[np.int64] = cells.astype(np.int64, copy=False)
        if cells64.size and not (cells64.min() >= 0 and cells64.max() < self.spec.n_cells):
            raise ValueError(f"flat cell indices must be 0..{self.spec.n_cells - 1}, got {cells.min()}..{cells.max()}")
        return cells64

    # --- accounting ------------------------------------------------------------------------------
    @property
    def n_live_chunks(self) -> int:
        """Pool slots held by at least one map (the scratch chunk excluded)."""
        return int(np.count_nonzero(self._refcount[1:]))

    @property
    def nbytes(self) -> int:
        """Bytes held by the pool, tables and scratch arrays."""
        arrays = (self._table, self._mark, self._pool, self._stamp, self._refcount, self._free)
        return int(sum(a.nbytes for a in arrays))
