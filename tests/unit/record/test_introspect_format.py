"""How `palpate topic echo` prints messages and how `topic hz` measures rates."""

from __future__ import annotations

import numpy as np

from palpate.commands.introspect import RateMeter, format_message, format_value, topic_table
from palpate.runtime.bus import Manifest
from tests.unit.record.synthetic import contacts


def test_small_arrays_are_printed_and_large_ones_summarised() -> None:
    assert format_value(np.array([1.0, 2.0])) == "[1., 2.]"
    big = format_value(np.array([[0.0, 1.0, 2.0], [3.0, np.nan, 5.0], [6.0, 7.0, 8.0]]))
    assert big.startswith("<float64 (3, 3) min 0 max 8 mean 4") and "1 non-finite" in big
    assert format_value(["a"] * 10) == "['a', 'a', 'a', ... (10 items)]"
    assert format_value(np.arange(10), full=True).count(",") == 9
    text = format_message("sensors/contacts", contacts(2_500_000_000, n=4))
    assert text.splitlines()[0] == "--- sensors/contacts [ContactSet v1] at 2.500000 s"
    assert "positions_m [m]: <float64 (4, 3)" in text and "forces_n [N]: [1., 1., 1., 1.]" in text


def test_rates_over_a_window_in_wall_and_sim_time() -> None:
    meter = RateMeter(window=5)
    for i in range(20):
        meter.add(0.1 * i, i * 20_000_000)  # 10 Hz wall clock, 50 Hz sim time
    assert meter.total == 20 and len(meter.arrivals) == 5
    np.testing.assert_allclose(meter.wall_hz(), 10.0, rtol=1e-9)
    np.testing.assert_allclose(meter.sim_hz(), 50.0, rtol=1e-9)
    assert RateMeter(3).report().endswith("not enough for a rate")
    # a replay that loops starts sim time again: the window starts again (it read 0.00 Hz sim across the wrap)
    meter.add(2.0, 0)
    meter.add(2.1, 20_000_000)
    assert len(meter.stamps) == 2 and meter.total == 22
    np.testing.assert_allclose(meter.sim_hz(), 50.0, rtol=1e-9)
    # publishers a tick apart, interleaved (lockstep acknowledgements): no new start
    meter.add(2.2, 30_000_000)
    meter.add(2.3, 25_000_000)
    assert len(meter.stamps) == 4


def test_topic_table_joins_publishers_and_subscribers() -> None:
    manifests = [
        Manifest(node="cube", endpoint="ipc://x/cube.pub", pid=1, publishes={"a": "A"}, subscribes={}),
        Manifest(node="est", endpoint="ipc://x/est.pub", pid=2, publishes={"b": "B"}, subscribes={"a": "A"}),
    ]
    assert topic_table(manifests) == {
        "a": {"type": "A", "publishers": ["cube"], "subscribers": ["est"]},
        "b": {"type": "B", "publishers": ["est"], "subscribers": []},
    }
