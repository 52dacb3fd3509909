"""The speed-accuracy trade of the mapper: map RMSE, ms per update and peak memory against K and
resolution, on the synthetic finger-taps-a-cube scene (synthetic.py).

``sweep`` simulates the scene once, adds Gaussian joint noise (sigma_deg) to the true angles, and
maps the same stream with: the known pose (true angles), dead reckoning (noisy angles, one map) and
FastSLAM for each K, at each resolution. The RMSE is the one of ``palpate eval slam`` (docs/slam.md):
``metrics.map_rmse`` over the surface band of the cube restricted to the cells the finger observed at
its true pose (the cells whose log-odds the known-pose mapper changed), so that cells nobody saw do
not dilute the comparison. Accuracy and completeness use the explored surface (within
``explored_radius_m`` of a true contact).
"""

from __future__ import annotations

import gc
import time
import tracemalloc
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from palpate.nodes.mapper.core import Mapper, MapperConfig
from palpate.nodes.mapper.kinematics import KinematicChain
from palpate.nodes.mapper.metrics import box_sdf, box_surface_points, map_rmse, surface_band, surface_distances_mm
from palpate.nodes.mapper.synthetic import CUBE_CENTER_M, CUBE_HALF_M, TappingRecord, simulate_tapping


@dataclass(frozen=True)
class SweepRow:
    """One configuration's result. K = 0 for the single-map methods (known, dead_reckoning)."""

    method: str
    K: int
    resolution_mm: float
    rmse: float
    accuracy_mm: float
    completeness_mm: float
    ms_per_update: float
    cpu_ms_per_update: float
    peak_memory_mb: float

    def as_dict(self) -> dict[str, float | int | str]:
        return asdict(self)


def _feed(mapper: Mapper, q_stream: NDArray[np.float64], rec: TappingRecord) -> None:
    for t in range(len(q_stream)):
        mapper.update(q_stream[t], rec.contact_links[t], rec.contact_local_m[t])


def _run(
    config: MapperConfig,
    chain: KinematicChain,
    q_stream: NDArray[np.float64],
    rec: TappingRecord,
    seed: int,
    measure_memory: bool,
) -> tuple[Mapper, float, float, float]:
    """Feed the stream; returns (mapper, wall ms per update, CPU ms per update, peak MB or nan).

    Timing comes from a first pass without tracemalloc (which would slow numpy's many small
    allocations by half); the peak memory from a second, identical pass under tracemalloc.
    """
    gc.collect()
    mapper = Mapper(config, chain, np.random.default_rng(seed))
    t0, c0 = time.perf_counter(), time.process_time()
    _feed(mapper, q_stream, rec)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    peak = np.nan
    if measure_memory:
        gc.collect()
        tracemalloc.start()
        _feed(Mapper(config, chain, np.random.default_rng(seed)), q_stream, rec)
        peak = tracemalloc.get_traced_memory()[1] / 2**20
        tracemalloc.stop()
    n = max(1, len(q_stream))
    return mapper, 1e3 * wall / n, 1e3 * cpu / n, peak


def sweep(
    Ks: Sequence[int] = (1, 10, 30, 100, 300),
    resolutions_mm: Sequence[float] = (1.0, 2.0, 4.0),
    *,
    duration_s: float = 10.0,
    update_hz: float = 100.0,
    sigma_deg: float = 1.5,
    seed: int = 0,
    band_m: float = 0.004,
    explored_radius_m: float = 0.010,
    measure_memory: bool = True,
    baselines: bool = True,
) -> list[SweepRow]:
    """Rows (method, K, resolution_mm, rmse, accuracy_mm, completeness_mm, ms_per_update,
    cpu_ms_per_update, peak_memory_mb) for FastSLAM at every K x resolution, plus known pose and
    dead reckoning per resolution when ``baselines`` (the known-pose mapper runs regardless: its map
    defines the observed cells of the RMSE region, module docstring).

    ms_per_update is wall-clock time of ``Mapper.update`` (what must stay under 1000 / update_hz
    to keep up); cpu_ms_per_update is the process CPU time, which a busy machine inflates less.
    Peak memory is the peak of what Python and numpy allocate while the mapper runs (tracemalloc,
    in a second pass over the same stream so that it does not slow the timed pass), from the
    mapper's creation to the last update.
    """
    chain, rec = simulate_tapping(duration_s, update_hz)
    rng = np.random.default_rng(seed)
    q_noisy = rec.q_true + np.radians(sigma_deg) * rng.standard_normal(rec.q_true.shape)
    contacts = np.concatenate([c for c in rec.contact_world_m if len(c)] or [np.zeros((0, 3))])
    tree = cKDTree(contacts) if len(contacts) else None
    centre = np.asarray(CUBE_CENTER_M)
    half = np.full(3, CUBE_HALF_M)

    def sdf(p: NDArray[np.float64]) -> NDArray[np.float64]:
        return box_sdf(p, centre, half)

    def explored(p: NDArray[np.float64]) -> NDArray[np.bool_]:
        if tree is None:
            return np.zeros(len(p), dtype=np.bool_)
        d, _ = tree.query(p, distance_upper_bound=explored_radius_m)
        return np.asarray(np.isfinite(d))

    surface = box_surface_points(centre, half, 0.001)
    surface = surface[explored(surface)]
    lo = centre - half - np.array([0.05, 0.03, 0.03])
    hi = centre + half + np.array([0.03, 0.03, 0.06])
    rows = []
    for res_mm in resolutions_mm:
        base = MapperConfig(
            region_min_m=(float(lo[0]), float(lo[1]), float(lo[2])),
            region_max_m=(float(hi[0]), float(hi[1]), float(hi[2])),
            resolution_m=res_mm * 1e-3,
            sigma_deg=sigma_deg,
        )
        known = _replace(base, mode="known")
        # the known-pose run comes first: its map defines the observed cells O of the RMSE region B & O
        runs: list[tuple[str, int, MapperConfig, NDArray[np.float64]]] = [("known", 0, known, rec.q_true)]
        if baselines:
            runs.append(("dead_reckoning", 0, known, q_noisy))
        runs += [("fastslam", int(K), _replace(base, n_particles=int(K)), q_noisy) for K in Ks]
        region: tuple[NDArray[np.int64], NDArray[np.bool_]] | None = None
        for method, K, config, stream in runs:
            mapper, ms, cpu_ms, peak = _run(config, chain, stream, rec, seed + 1, measure_memory)
            m = mapper.best_map()
            if region is None:
                band, band_truth = surface_band(mapper.spec, sdf, band_m)
                seen = np.isin(band, m.flat)
                region = (band[seen], band_truth[seen])
                if not baselines:
                    continue
            acc, comp = surface_distances_mm(m, sdf, surface)
            rows.append(
                SweepRow(
                    method=method,
                    K=K,
                    resolution_mm=float(res_mm),
                    rmse=map_rmse(m, *region),
                    accuracy_mm=acc,
                    completeness_mm=comp,
                    ms_per_update=ms,
                    cpu_ms_per_update=cpu_ms,
                    peak_memory_mb=float(peak),
                )
            )
    return rows


def _replace(config: MapperConfig, **changes: object) -> MapperConfig:
    from dataclasses import replace

    return replace(config, **changes)  # type: ignore[arg-type]


def format_rows(rows: Sequence[SweepRow]) -> str:
    """A fixed-width text table of sweep rows."""
    head = (
        f"{'method':<15}{'K':>5}{'res_mm':>8}{'rmse':>8}{'acc_mm':>8}{'comp_mm':>9}"
        f"{'ms/upd':>9}{'cpu_ms':>9}{'peak_MB':>9}"
    )
    lines = [head]
    for r in rows:
        lines.append(
            f"{r.method:<15}{r.K:>5}{r.resolution_mm:>8.1f}{r.rmse:>8.3f}{r.accuracy_mm:>8.2f}"
            f"{r.completeness_mm:>9.2f}{r.ms_per_update:>9.2f}{r.cpu_ms_per_update:>9.2f}{r.peak_memory_mb:>9.1f}"
        )
    return "\n".join(lines)
