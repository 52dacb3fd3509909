"""The Mapper facade: configuration, input checks, counters, outputs."""

from __future__ import annotations

import ast
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from palpate.errors import ConfigError, EstimationError
from palpate.nodes.mapper.core import Mapper, MapperConfig
from palpate.nodes.mapper.kinematics import KinematicChain
from tests.unit.mapper.synthetic import TappingRecord, simulate_tapping

REGION = {"region_min_m": (-0.03, -0.06, -0.06), "region_max_m": (0.12, 0.06, 0.06)}


@pytest.fixture(scope="module")
def scene() -> tuple[KinematicChain, TappingRecord]:
    return simulate_tapping(0.5)


def _contact_step(rec: TappingRecord) -> int:
    return next(t for t in range(len(rec.q_true)) if len(rec.contact_links[t]))


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"mode": "gps"}, "mode"),
        ({"n_particles": 0}, "n_particles"),
        ({"sigma_deg": -1.0}, "sigma_deg"),
        ({"sigma_deg": math.nan}, "sigma_deg"),
        ({"l_occ": -1.0}, "l_occ"),
        ({"resolution_m": 0.0}, "resolution_m"),
        ({"region_max_m": (0.12, -0.07, 0.06)}, "must exceed"),
        ({"free_margin_m": -0.001}, "free_margin_m"),
        ({"chunk_edge": 6}, "chunk_edge must be a power of two, got 6"),
        ({"l_min": 0.5}, "l_min must be < 0"),
        ({"l_max": -1.0}, "l_max must be > 0"),
        ({"l_max": math.inf}, "l_max"),
        ({"likelihood_floor": 0.7}, "likelihood_floor"),  # FastSlam needs (0, 0.5): it passed the dry run
        ({"likelihood_floor": 0.0}, "likelihood_floor"),
    ],
)
def test_bad_config_values_are_quoted(changes: dict[str, object], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        MapperConfig(**{**REGION, **changes})  # type: ignore[arg-type]


def test_defaults_are_the_paper_values() -> None:
    c = MapperConfig(**REGION)  # type: ignore[arg-type]
    assert c.sigma_deg == 1.5 and c.l_occ == pytest.approx(math.log(9.0))
    assert c.l_free == pytest.approx(-math.log(9.0)) and c.resample_threshold == 0.5


@pytest.mark.parametrize("mode", ["known", "fastslam"])
def test_bad_input_is_rejected_and_changes_nothing(scene: tuple[KinematicChain, TappingRecord], mode: str) -> None:
    chain, rec = scene
    m = Mapper(MapperConfig(**REGION, mode=mode, n_particles=4), chain, np.random.default_rng(0))  # type: ignore[arg-type]
    t = _contact_step(rec)
    m.update(rec.q_true[t], rec.contact_links[t], rec.contact_local_m[t])
    before = m.best_map()
    bad_q = rec.q_true[t].copy()
    bad_q[2] = np.nan
    cases = [
        (bad_q, rec.contact_links[t], rec.contact_local_m[t], "not finite"),
        (rec.q_true[t][:3], rec.contact_links[t], rec.contact_local_m[t], "shape"),
        (rec.q_true[t], np.array([7]), np.zeros((1, 3)), "outside"),
        (rec.q_true[t], np.array([3]), np.zeros((1, 3)), r"outside 0\.\.2"),  # the chain has links 0, 1, 2
        (rec.q_true[t], np.array([-1]), np.zeros((1, 3)), r"outside 0\.\.2"),  # not numpy's last link
        (rec.q_true[t], np.array([0, 1]), np.zeros((1, 3)), "contact links"),
        (rec.q_true[t], np.array([0]), np.full((1, 3), np.inf), "not finite"),
        (rec.q_true[t], np.array([1, 1]), np.zeros((1, 6)), r"positions \(n, 3\); got shapes \(2,\) and \(1, 6\)"),
        (rec.q_true[t], np.array([1, 1]), np.zeros((3, 2)), r"got shapes \(2,\) and \(3, 2\)"),
        (rec.q_true[t], np.array([[1]]), np.zeros((1, 3)), r"got shapes \(1, 1\) and \(1, 3\)"),
    ]
    for q, links, local, message in cases:
        with pytest.raises(EstimationError, match=message):
            m.update(q, links, local)
    assert m.counters.updates == 1
    after = m.best_map()
    np.testing.assert_array_equal(after.flat, before.flat)
    np.testing.assert_array_equal(after.log_odds, before.log_odds)
    m.update(rec.q_true[t + 1], rec.contact_links[t + 1], rec.contact_local_m[t + 1])  # carries on
    assert m.counters.updates == 2


def test_counters_and_timing(scene: tuple[KinematicChain, TappingRecord]) -> None:
    chain, rec = scene
    m = Mapper(MapperConfig(**REGION, n_particles=5), chain, np.random.default_rng(1))  # type: ignore[arg-type]
    for t in range(len(rec.q_true)):
        m.update(rec.q_true[t], rec.contact_links[t], rec.contact_local_m[t])
    c = m.counters
    assert c.updates == len(rec.q_true)
    assert c.contacts == sum(len(x) for x in rec.contact_links) > 0
    assert c.mean_update_ms > 0 and math.isfinite(c.last_update_ms)
    assert c.free_points_outside == 0 and c.contacts_outside == 0
    assert 1 < c.resamples <= c.updates  # every resampling since the start (5 particles resample often)
    est = m.pose_estimate()
    assert est.mean_q_rad.shape == (4,) and est.best_q_rad.shape == (4,)


def test_points_outside_the_region_are_ignored_and_counted(scene: tuple[KinematicChain, TappingRecord]) -> None:
    chain, rec = scene
    small = {"region_min_m": (0.04, -0.03, -0.01), "region_max_m": (0.09, 0.03, 0.03)}
    m = Mapper(MapperConfig(**small, mode="known"), chain, np.random.default_rng(2))  # type: ignore[arg-type]
    t = _contact_step(rec)
    m.update(rec.q_true[t], rec.contact_links[t], rec.contact_local_m[t])
    assert 0 < m.counters.free_points_outside < m.free_volume.n_points
    far = np.array([[0.0, 0.5, 0.0]])  # a contact 0.5 m off the link: outside the region
    m.update(rec.q_true[t], np.array([0]), far)
    assert m.counters.contacts_outside == 1
    assert m.n_eff == 1.0


def test_contacts_outside_where_the_reading_puts_them_are_counted_apart_from_the_particles(
    scene: tuple[KinematicChain, TappingRecord],
) -> None:
    """An outside walkthrough: at 5 deg of joint noise the mapper said a contact lay outside the region, while
    every true contact lay 16 mm inside it: only particles had placed some there."""
    chain, rec = scene
    m = Mapper(MapperConfig(**REGION, sigma_deg=30.0), chain, np.random.default_rng(2))  # type: ignore[arg-type]
    for t in range(len(rec.q_true)):
        m.update(rec.q_true[t], rec.contact_links[t], rec.contact_local_m[t])
    c = m.counters
    assert c.contacts_outside > 0 and c.contacts_outside_measured == 0
    m.update(rec.q_true[0], np.array([0]), np.array([[0.0, 0.5, 0.0]]))  # this one lies outside as read
    assert m.counters.contacts_outside_measured == 1
    with pytest.raises(EstimationError, match=r"contact links must be link indices \(integers\), got dtype float64"):
        m.update(rec.q_true[0], np.array([2.0]), np.zeros((1, 3)))


def test_known_mode_outputs_are_the_one_map(scene: tuple[KinematicChain, TappingRecord]) -> None:
    chain, rec = scene
    m = Mapper(MapperConfig(**REGION, mode="known"), chain, np.random.default_rng(3))  # type: ignore[arg-type]
    for t in range(len(rec.q_true)):
        m.update(rec.q_true[t], rec.contact_links[t], rec.contact_local_m[t])
    assert m.filter is None
    np.testing.assert_array_equal(m.weighted_map().log_odds, m.best_map().log_odds)
    np.testing.assert_array_equal(m.pose_estimate().best_q_rad, rec.q_true[-1])
    occupied = m.best_map().flat[m.best_map().log_odds > 0]
    assert len(occupied) > 0
    # contact cells lie on the cube's top face (z = 0), within a cell
    centres = m.spec.centers(occupied)
    assert np.all(np.abs(centres[:, 2]) <= m.spec.resolution_m)


def test_free_spacing_and_margin_change_the_free_volume(scene: tuple[KinematicChain, TappingRecord]) -> None:
    chain, _ = scene
    base = MapperConfig(**REGION, mode="known")  # type: ignore[arg-type]
    dense = Mapper(base, chain, np.random.default_rng(0)).free_volume.n_points
    sparse = Mapper(replace(base, free_spacing_m=0.004), chain, np.random.default_rng(0)).free_volume.n_points
    thin = Mapper(replace(base, free_margin_m=0.006), chain, np.random.default_rng(0)).free_volume.n_points
    assert sparse < dense / 4 and thin < dense


def test_settings_that_would_not_fit_in_memory_are_refused_before_allocating(
    scene: tuple[KinematicChain, TappingRecord],
) -> None:
    """An outside audit: n_particles 1e11 (78.9 TiB of chunk table) and a 0.1 mm grid with 100 particles
    (26 GB of free-volume arrays at the first contact) ended in numpy's allocation errors."""
    chain, _ = scene
    from palpate.nodes.mapper.core import lattice_points

    base = MapperConfig(**REGION)  # type: ignore[arg-type]
    for spacing, margin in ((0.002, 0.002), (0.004, 0.001), (0.001, 0.006)):
        lattice = Mapper(
            replace(base, mode="known", free_spacing_m=spacing, free_margin_m=margin), chain, np.random.default_rng(0)
        )
        n = lattice.free_volume.n_points
        assert n <= lattice_points(chain, spacing, margin) <= 2 * n  # the boxes around the capsules
    with pytest.raises(
        ConfigError,
        match=r"n_particles = 100000000000 maps need .* GiB .* for the maps' chunk table \(\d+ chunks of 8\^3 cells",
    ):
        Mapper(replace(base, n_particles=100_000_000_000), chain, np.random.default_rng(0))
    with pytest.raises(
        ConfigError,
        match=r"maps need .* GiB at resolution_m = 5e-05 for one update's free-volume arrays \([\d,]+ free-volume",
    ):
        small = replace(base, region_min_m=(0.0, 0.0, 0.0), region_max_m=(0.01, 0.01, 0.01))  # a small table
        Mapper(replace(small, resolution_m=5e-05), chain, np.random.default_rng(0))


@pytest.mark.parametrize("mode", ["known", "fastslam"])
def test_cells_as_large_as_the_finger_keep_its_contacts(scene: tuple[KinematicChain, TappingRecord], mode: str) -> None:
    """An outside audit: with 8 mm cells and more the finger's free volume fell back to points on its
    axes, in the cells it touches, and cleared the contacts' cells (at 10 cm none stayed). A capsule
    thinner than the free margin now gives no free volume."""
    chain, rec = scene
    config = MapperConfig(**REGION, mode=mode, resolution_m=0.01, n_particles=5)  # type: ignore[arg-type]
    m = Mapper(config, chain, np.random.default_rng(4))
    assert m.free_volume.n_points == 0
    for t in range(len(rec.q_true)):
        m.update(rec.q_true[t], rec.contact_links[t], rec.contact_local_m[t])
    assert np.count_nonzero(m.best_map().log_odds > 0) > 0


def test_cores_import_no_sockets() -> None:
    folder = Path(__file__).resolve().parents[3] / "nodes" / "mapper"
    for path in folder.glob("*.py"):
        tree = ast.parse(path.read_text())
        names = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
        names |= {n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
        assert not any(n.split(".")[0] == "zmq" or "codec" in n for n in names), path.name


def test_the_chunk_table_counts_partial_chunks(monkeypatch: pytest.MonkeyPatch) -> None:
    """A 9 x 9 x 9 grid in chunks of 8: ceil(9 / 8)^3 + 1 = 9 chunks, 4 bytes each for 1000 maps: 36 kB,
    more than a machine of 20 kB (floor(9 / 8)^3 + 1 = 2 chunks would fit)."""
    from palpate.nodes.mapper import core
    from palpate.nodes.mapper.grid import GridSpec

    config = MapperConfig(region_min_m=(0.0, 0.0, 0.0), region_max_m=(0.018, 0.018, 0.018), n_particles=1000)
    spec = GridSpec.from_bounds(config.region_min_m, config.region_max_m, config.resolution_m)
    assert spec.shape == (9, 9, 9) and config.chunk_edge == 8
    memory = {"SC_PAGE_SIZE": 1, "SC_PHYS_PAGES": 20_000}
    monkeypatch.setattr(core.os, "sysconf", lambda name: memory[name])
    with pytest.raises(ConfigError, match="chunk table"):
        core.check_memory(config, spec, 1000, 0)
    memory["SC_PHYS_PAGES"] = 36_000
    core.check_memory(config, spec, 1000, 0)  # exactly fits


def test_a_fine_grid_keeps_its_contact_cells_with_the_default_margin(
    scene: tuple[KinematicChain, TappingRecord],
) -> None:
    """An outside audit: at 0.5 mm cells and below the one-cell margin cleared the cells of the contacts
    (the finger presses into the surface), and the map came out nearly empty without a word."""
    from palpate.nodes.mapper.core import measured_free_margin_m

    assert measured_free_margin_m(0.0005) == pytest.approx(0.0015) == measured_free_margin_m(0.0001)
    assert measured_free_margin_m(0.002) == pytest.approx(0.0005) and measured_free_margin_m(0.003) is None
    chain, rec = scene
    occupied = {}
    for margin in ("auto", None):
        config = MapperConfig(**REGION, mode="known", resolution_m=0.0005, free_margin_m=margin)  # type: ignore[arg-type]
        assert (margin == "auto") == (MapperConfig(**REGION).free_margin_m == margin)  # type: ignore[arg-type]
        mapper = Mapper(config, chain, np.random.default_rng(0))
        for t in range(len(rec.q_true)):
            mapper.update(rec.q_true[t], rec.contact_links[t], rec.contact_local_m[t])
        occupied[margin] = int((mapper.best_map().log_odds > 0).sum())
    assert occupied["auto"] >= 2 * occupied[None] >= 2


def test_whole_cells_asks_the_farthest_corner_of_each_points_cell_to_lie_within_its_depth() -> None:
    from palpate.nodes.mapper.observation import whole_cells

    f = np.array([[[0.5, 3.1, 7.0], [0.5, 0.5, 2.25], [0.5, 0.5, 1.0]]], dtype=np.float32)  # (K=1, 3, P=3)
    half_diagonal = math.sqrt(3) / 2  # from the centre of its cell
    off_centre = math.sqrt(0.9**2 + 0.5**2 + 0.5**2)  # (0.1, 0.5, 0.5) into its cell: 0.9 to the far face
    corner = math.sqrt(3)  # on a corner, the opposite one is a whole diagonal away
    depth = np.array([half_diagonal + 1e-4, off_centre - 1e-4, corner], dtype=np.float32)
    assert whole_cells(f, depth).tolist() == [[True, False, True]]


@pytest.mark.parametrize("mode", ["known", "fastslam"])
def test_free_margin_cell_clears_no_contact_cell_wherever_the_grid_lies(
    scene: tuple[KinematicChain, TappingRecord], mode: str
) -> None:
    """An outside walkthrough: the measured 0.5 mm margin at 2 mm cells kept the Rubik's cube's contact
    cells only where its faces lie 0.5 mm inside their cells; with the region 1 mm off, the sphere, the
    torus or a YCB mesh, free updates cleared 20-60 % of them. ``cell`` clears a cell only when it lies
    wholly in the finger, so no contact cell ends free, at any offset of the grid."""
    chain, rec = scene
    freed = {}
    for margin in ("auto", "cell"):
        for shift in (0.0, 0.5e-3, 1.0e-3, 1.5e-3):
            region = {k: tuple(v - shift for v in REGION[k]) for k in REGION}
            config = MapperConfig(**region, mode=mode, n_particles=3, sigma_deg=0.0, free_margin_m=margin)  # type: ignore[arg-type]
            mapper = Mapper(config, chain, np.random.default_rng(0))
            for t in range(len(rec.q_true)):
                mapper.update(rec.q_true[t], rec.contact_links[t], rec.contact_local_m[t])
            grid = mapper.best_map()
            lut = dict(zip(grid.flat.tolist(), grid.log_odds.tolist(), strict=True))
            world = np.concatenate([w.reshape(-1, 3) for w in rec.contact_world_m])
            cells = np.floor((world - np.asarray(region["region_min_m"])) / config.resolution_m)
            flat = np.unique(np.ravel_multi_index(cells.astype(int).T, grid.spec.shape))
            values = np.array([lut.get(int(c), 0.0) for c in flat])
            freed[margin, shift] = int((values < 0).sum())
            assert (grid.log_odds < 0).sum() > 10 * len(flat) or margin == "auto"  # it still maps free space
    assert all(freed["cell", shift] == 0 for shift in (0.0, 0.5e-3, 1.0e-3, 1.5e-3)), freed
    assert max(freed["auto", shift] for shift in (0.0, 0.5e-3, 1.0e-3, 1.5e-3)) > 0, freed


def test_free_margin_cell_counts_as_outside_only_the_points_outside_the_region() -> None:
    """A review: points both outside the region and too shallow were taken off the outside count."""
    from palpate.nodes.mapper.grid import GridSpec, LogOddsGrids
    from palpate.nodes.mapper.observation import observation_keys

    grids = LogOddsGrids(GridSpec(origin_m=(0.0, 0.0, 0.0), resolution_m=0.001, shape=(8, 8, 8)), 1)
    points = np.array([[0.0035, 0.0035, 0.0035], [0.0035, 0.0035, 0.02], [-0.01, 0.0035, 0.0035]])  # in, out, out
    free_h = (np.vstack([points.T, np.ones((1, 3))]).astype(np.float32),)
    shallow = (np.full(3, 0.1, dtype=np.float32),)  # a tenth of a cell deep: no whole cell
    rots, pos = np.eye(3)[None, None], np.zeros((1, 1, 3))
    links, local = np.zeros(0, dtype=np.intp), np.zeros((0, 3))
    free, _ = observation_keys(grids, rots, pos, free_h, links, local, shallow)
    assert free.n_outside == 2 and free.valid is not None and not free.valid.any()
    free, _ = observation_keys(grids, rots, pos, free_h, links, local)  # no depths: every point in the region clears
    assert free.n_outside == 2 and free.valid is not None and free.valid.tolist() == [[True, False, False]]
