"""MapperSession: the mapper node's decisions (joint order, contacts on the chain, pairing by stamp,
the map schedule, the resampled flag, the label), against a recording fake Mapper and a real one."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np
import pytest

from palpate.description import load_hand
from palpate.errors import InputError
from palpate.nodes.mapper.core import Mapper, MapperConfig, MapperCounters
from palpate.nodes.mapper.kinematics import FingerMount, KinematicChain
from palpate.nodes.mapper.session import MapperSession

REGION = {"region_min_m": (-0.045, -0.045, -0.045), "region_max_m": (0.045, 0.045, 0.045)}
MS = 1_000_000


@pytest.fixture(scope="module")
def chain() -> KinematicChain:
    return KinematicChain.from_description(load_hand(), FingerMount())


@dataclass
class FakeMapper:
    """Records each update; resamples at the updates (1-based) listed in resample_at."""

    chain: KinematicChain
    config: MapperConfig
    resample_at: set[int] = field(default_factory=set)
    counters: MapperCounters = field(default_factory=MapperCounters)
    calls: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=list)

    def update(self, q_rad: np.ndarray, contact_links: np.ndarray, contact_local_m: np.ndarray) -> None:
        self.calls.append((np.array(q_rad), np.array(contact_links), np.array(contact_local_m)))
        self.counters.updates += 1
        self.counters.resamples += int(len(self.calls) in self.resample_at)


def _session(
    chain: KinematicChain, mode: str = "fastslam", period_s: float = 1.0, label: str = "", **fake: Any
) -> tuple[MapperSession, FakeMapper]:
    mapper = FakeMapper(chain, MapperConfig(**REGION, mode=mode), **fake)  # type: ignore[arg-type]
    return MapperSession(cast(Mapper, mapper), period_s, label), mapper


def test_reading_is_put_in_the_chain_order_and_other_joints_are_ignored(chain: KinematicChain) -> None:
    session, mapper = _session(chain)
    names = ["thumb_cmc", *chain.joint_names[::-1], "middle_pip"]
    q = np.array([9.0, 0.4, 0.3, 0.2, 0.1, 8.0])
    reading = session.joint_reading(names, q, 5 * MS)
    assert chain.joint_names == ["index_mcp_abd", "index_mcp_flex", "index_pip", "index_dip"]
    np.testing.assert_array_equal(reading.q_rad, [0.1, 0.2, 0.3, 0.4])
    assert session.tick(5 * MS) is not None
    [(q_used, links, local)] = mapper.calls
    np.testing.assert_array_equal(q_used, [0.1, 0.2, 0.3, 0.4])
    assert links.shape == (0,) and local.shape == (0, 3)  # no contacts received


def test_reading_without_a_chain_joint_is_refused_and_the_previous_one_kept(chain: KinematicChain) -> None:
    session, mapper = _session(chain)
    session.joint_reading(chain.joint_names, np.arange(4.0), 0)
    with pytest.raises(InputError, match=r"names: lacks 1 of the 4 names needed: 'index_pip'"):
        session.joint_reading(["index_mcp_abd", "index_mcp_flex", "index_dip"], np.zeros(3), 10 * MS)
    session.tick(10 * MS)
    np.testing.assert_array_equal(mapper.calls[0][0], np.arange(4.0))


def test_a_reading_beyond_a_full_turn_is_refused_as_degrees_sent_as_radians(chain: KinematicChain) -> None:
    session, mapper = _session(chain)
    session.joint_reading(chain.joint_names, np.full(4, -6.28), 0)  # a full turn less a little: a hinge angle
    with pytest.raises(InputError, match=r"positions_rad: joint 'index_mcp_flex' reads 45 rad, more than a full turn"):
        session.joint_reading(chain.joint_names, np.array([0.1, 45.0, 30.0, 10.0]), 10 * MS)
    session.tick(10 * MS)
    np.testing.assert_array_equal(mapper.calls[0][0], np.full(4, -6.28))  # the previous reading


def test_a_reading_beyond_a_full_turn_either_way_is_refused(chain: KinematicChain) -> None:
    session, _ = _session(chain)
    with pytest.raises(InputError, match=r"joint 'index_mcp_flex' reads -45 rad, more than a full turn"):
        session.joint_reading(chain.joint_names, np.array([0.1, -45.0, 0.0, 0.0]), 0)


def test_only_contacts_on_the_chain_are_kept_as_link_indices(chain: KinematicChain) -> None:
    session, _ = _session(chain)
    local = np.arange(15.0).reshape(5, 3)
    kept = session.contacts(["index_distal", "palm", "index_proximal", "thumb_distal", "index_distal"], local, 0)
    assert chain.link_names == ["index_proximal", "index_middle", "index_distal"]
    assert kept.links.dtype == np.int64
    np.testing.assert_array_equal(kept.links, [2, 0, 2])
    np.testing.assert_array_equal(kept.local_m, local[[0, 2, 4]])
    none = session.contacts(["palm"], np.ones((1, 3)), 0)
    assert none.links.shape == (0,) and none.local_m.shape == (0, 3)


def test_contacts_join_the_reading_of_the_same_stamp_only(chain: KinematicChain) -> None:
    session, mapper = _session(chain)
    q = np.zeros(4)
    session.contacts(["index_middle"], np.array([[0.01, 0.0, 0.005]]), 10 * MS)
    session.joint_reading(chain.joint_names, q, 10 * MS)
    session.tick(10 * MS)
    session.joint_reading(chain.joint_names, q, 20 * MS)  # the contacts are of the tick before
    session.tick(20 * MS)
    (_, links1, local1), (_, links2, local2) = mapper.calls
    np.testing.assert_array_equal(links1, [1])
    np.testing.assert_array_equal(local1, [[0.01, 0.0, 0.005]])
    assert links2.shape == (0,) and local2.shape == (0, 3)


def test_contacts_stamped_apart_from_every_reading_are_counted_once_and_a_tolerance_joins_them(
    chain: KinematicChain,
) -> None:
    """An outside walkthrough: contacts stamped 1 ns from the joint reading were dropped without a count (a
    driver's joint and tactile streams are stamped apart)."""
    session, mapper = _session(chain)
    contact = (["index_distal", "index_distal"], np.array([[0.0, 0.0, 0.01], [0.0, 0.001, 0.01]]))
    for tick in range(1, 4):
        session.joint_reading(chain.joint_names, np.zeros(4), tick * 10 * MS)
        session.contacts(*contact, tick * 10 * MS + 1)
        session.tick(tick * 10 * MS)
    session.joint_reading(chain.joint_names, np.zeros(4), 40 * MS)
    session.tick(40 * MS)  # no new contacts: the last set is not counted again
    assert session.contacts_unmatched == 6 and session.last_unmatched == (30 * MS + 1, 40 * MS)
    assert all(len(links) == 0 for _, links, _ in mapper.calls)
    # real time: the noisy reading of a stamp comes a tick after its contacts (a hop through the noise node)
    late, mapper = _session(chain)
    for tick in range(1, 4):
        late.contacts(*contact, tick * 10 * MS)
        if tick > 1:
            late.joint_reading(chain.joint_names, np.zeros(4), (tick - 1) * 10 * MS)
        late.tick(tick * 10 * MS)
    assert late.contacts_unmatched == 0 and [len(links) for _, links, _ in mapper.calls] == [2, 2]
    mapper = FakeMapper(chain, MapperConfig(**REGION))  # type: ignore[arg-type]
    tolerant = MapperSession(cast(Mapper, mapper), 1.0, stamp_tolerance_s=0.002)
    tolerant.joint_reading(chain.joint_names, np.zeros(4), 10 * MS)
    tolerant.contacts(*contact, 11 * MS)
    tolerant.tick(10 * MS)
    assert tolerant.contacts_unmatched == 0 and len(mapper.calls[0][1]) == 2


def test_a_tick_without_a_new_reading_does_nothing(chain: KinematicChain) -> None:
    session, mapper = _session(chain)
    assert session.tick(0) is None
    session.joint_reading(chain.joint_names, np.zeros(4), 0)
    assert session.tick(0) is not None
    assert session.tick(10 * MS) is None  # the reading was used once
    assert len(mapper.calls) == 1


def test_maps_go_out_at_the_first_update_and_then_every_period(chain: KinematicChain) -> None:
    session, _ = _session(chain, period_s=0.05)
    due = []
    for k in range(16):
        if k not in (5, 6):  # no reading at 50 and 60 ms: the maps go out at the next update (70 ms)
            session.joint_reading(chain.joint_names, np.zeros(4), k * 10 * MS)
        step = session.tick(k * 10 * MS)
        if step is not None and step.publish_maps:
            due.append(k * 10)
    assert due == [0, 70, 120]
    assert session.next_publish_ns == 170 * MS


def test_resampled_reports_this_update_only(chain: KinematicChain) -> None:
    session, _ = _session(chain, resample_at={2, 3})
    flags = []
    for k in range(4):
        session.joint_reading(chain.joint_names, np.zeros(4), k)
        step = session.tick(k)
        assert step is not None
        flags.append(step.resampled)
    assert flags == [False, True, True, False]


@pytest.mark.parametrize(
    ("mode", "label", "expected"),
    [("known", "", "known"), ("fastslam", "", "best"), ("known", "dead_reckoning", "dead_reckoning")],
)
def test_label_of_the_best_map(chain: KinematicChain, mode: str, label: str, expected: str) -> None:
    assert _session(chain, mode=mode, label=label)[0].label == expected


def test_the_session_maps_as_the_mapper_fed_directly(chain: KinematicChain) -> None:
    """Messages in the hand's joint order with off-chain contacts give the map of direct updates."""
    config = MapperConfig(**REGION, mode="fastslam", n_particles=5, resolution_m=0.004)  # type: ignore[arg-type]
    direct = Mapper(config, chain, np.random.default_rng(3))
    session = MapperSession(Mapper(config, chain, np.random.default_rng(3)), 1.0)
    rng = np.random.default_rng(4)
    for k in range(6):
        q = np.radians([2.0, 10.0 + 5 * k, 20.0, 10.0]) + rng.normal(0, 0.01, 4)
        local = rng.normal(0, 0.005, (2, 3))
        direct.update(q, np.array([2, 1]), local)
        session.contacts(["index_distal", "thumb_distal", "index_middle"], np.insert(local, 1, 9.0, axis=0), k)
        session.joint_reading(["middle_pip", *chain.joint_names[::-1]], np.concatenate([[1.0], q[::-1]]), k)
        session.tick(k)
    a, b = direct.best_map(), session.mapper.best_map()
    assert len(a.flat) > 0  # something was mapped
    np.testing.assert_array_equal(a.flat, b.flat)
    np.testing.assert_array_equal(a.log_odds, b.log_odds)
    np.testing.assert_array_equal(direct.filter.weights, session.mapper.filter.weights)  # type: ignore[union-attr]
    assert direct.counters.contacts == session.mapper.counters.contacts == 12
