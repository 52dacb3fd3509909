"""RunControl: when the evaluator asks for the whole-object surface, what it scores, when the run ends."""

from __future__ import annotations

from typing import Any

import numpy as np

from palpate.nodes.explore_eval.core import EvalConfig, RunControl

S_NS = 1_000_000_000


class FakeEvaluator:
    """Stands in for ExplorationEvaluator: each touch reaches the scripted milestones and finish state."""

    def __init__(self, script: list[tuple[list[float], str]], config: EvalConfig | None = None) -> None:
        self.script = list(script)
        self.config = config or EvalConfig()
        self.finished = ""
        self.touches: list[tuple[Any, ...]] = []
        self.scored: list[tuple[float, Any]] = []
        self.shapes: list[int] = []  # contacts at each shape scoring
        self.shape_interval = self.config.shape_every_contacts  # a small object's

    def add_touch(self, *args: Any) -> list[float]:
        self.touches.append(args)
        reached, self.finished = self.script.pop(0)
        return reached

    def rmse(self, vertices_m: np.ndarray, faces: np.ndarray, vertex_variance: np.ndarray) -> Any:
        return ("scores of", len(vertices_m))

    def shape(self, vertices_m: np.ndarray, faces: np.ndarray, contacts: int | None = None) -> Any:
        self.shapes.append(len(self.touches) if contacts is None else contacts)
        return ("shape of", len(vertices_m))

    def set_rmse(self, fraction: float, scores: Any, shape: Any = None) -> None:
        assert shape == ("shape of", scores[1])  # the milestone's shape scores are of the same estimate
        self.scored.append((fraction, scores))


def touch(run: RunControl, stamp_ns: int, axis: np.ndarray | None = None) -> bool:
    return run.touch(stamp_ns, np.zeros(3), np.ones(3), 0.1, 5.0, axis, False)


def surface(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return np.zeros((n, 3)), np.zeros((0, 3), dtype=np.int32), np.zeros(n)


def test_a_milestone_asks_for_the_surface_and_the_next_surface_scores_it() -> None:
    ev = FakeEvaluator([([], ""), ([0.5], ""), ([], "")])
    run = RunControl(ev)  # type: ignore[arg-type]
    assert not touch(run, 1 * S_NS)
    assert touch(run, 2 * S_NS)
    assert not run.surface(*surface(7))  # scores 50 %; the run goes on
    assert ev.scored == [(0.5, ("scores of", 7))]
    assert not touch(run, 3 * S_NS)
    assert not run.surface(*surface(9))  # nothing waiting: nothing scored
    assert ev.scored == [(0.5, ("scores of", 7))]
    assert len(ev.touches) == 3


def test_the_finishing_touch_asks_for_the_last_surface_which_ends_the_run() -> None:
    ev = FakeEvaluator([([0.5, 0.8], "goal"), ([], "goal")])
    run = RunControl(ev)  # type: ignore[arg-type]
    assert touch(run, S_NS)
    assert not touch(run, 2 * S_NS) and len(ev.touches) == 1  # touches after the finishing one are ignored
    assert run.surface(*surface(4))
    assert ev.scored == [(0.5, ("scores of", 4)), (0.8, ("scores of", 4))]
    assert not run.tick(1000 * S_NS)  # finished: the watchdog is quiet


def test_a_budget_that_ends_the_run_without_a_milestone_also_asks_for_the_surface() -> None:
    ev = FakeEvaluator([([], "contact budget")])
    run = RunControl(ev)  # type: ignore[arg-type]
    assert touch(run, S_NS)
    assert run.surface(*surface(3)) and ev.scored == [] and ev.shapes == [1]


def test_every_nth_contact_asks_for_the_surface_for_its_shape_scores() -> None:
    ev = FakeEvaluator([([], "")] * 5 + [([0.5], "")], EvalConfig(shape_every_contacts=3))
    run = RunControl(ev)  # type: ignore[arg-type]
    asked = [touch(run, k * S_NS) for k in range(1, 4)]
    assert asked == [False, False, True]
    assert not run.needs_variance  # the shape scores need no GP variance: the GPIS node skips Eq. 6
    assert not run.surface(*surface(5)) and ev.shapes == [3] and ev.scored == []
    assert not run.surface(*surface(5)) and ev.shapes == [3]  # nothing waiting: nothing scored
    assert [touch(run, k * S_NS) for k in range(4, 7)] == [False, False, True]
    assert run.needs_variance  # a milestone waits: its confident RMSE reads the variance
    run.surface(*surface(6))
    assert not run.needs_variance
    assert ev.shapes == [3, 6] and ev.scored == [(0.5, ("scores of", 6))]


def test_the_checkpoints_follow_the_objects_shape_interval() -> None:
    """A large object's evaluator spaces its checkpoints wider than shape_every_contacts."""
    ev = FakeEvaluator([([], "")] * 8, EvalConfig(shape_every_contacts=2))
    ev.shape_interval = 4  # what EvalConfig.shape_interval gives an object with a large covering bound
    run = RunControl(ev)  # type: ignore[arg-type]
    assert [touch(run, k * S_NS) for k in range(1, 9)] == [False, False, False, True] * 2


def test_surfaces_answer_the_requests_in_order_so_a_late_one_is_not_the_last() -> None:
    """Off lockstep a checkpoint's surface can come after the finishing touch: it gets the checkpoint's
    shape scores (at its touch count), and only the next surface scores the milestones and ends the run."""
    ev = FakeEvaluator([([], ""), ([0.5, 0.8], "goal")], EvalConfig(shape_every_contacts=1))
    run = RunControl(ev)  # type: ignore[arg-type]
    assert touch(run, 1 * S_NS)  # a checkpoint
    assert touch(run, 2 * S_NS)  # the finishing touch, before the checkpoint's surface came
    assert run.needs_variance  # the last request carries milestones
    assert not run.surface(*surface(3))  # the checkpoint's surface: the run goes on
    assert ev.shapes == [1] and ev.scored == []
    assert run.surface(*surface(8))
    assert ev.shapes == [1, 2] and ev.scored == [(0.5, ("scores of", 8)), (0.8, ("scores of", 8))]
    assert not run.overdue(1000 * S_NS)


def test_a_request_never_answered_does_not_hold_up_the_later_ones() -> None:
    """The estimator refused the checkpoint's request: the surface after the finishing touch covers its
    contacts and answers both, ending the run with the milestones scored."""
    ev = FakeEvaluator([([], ""), ([0.5, 0.8], "goal")], EvalConfig(shape_every_contacts=1))
    run = RunControl(ev)  # type: ignore[arg-type]
    assert touch(run, 1 * S_NS) and touch(run, 2 * S_NS)
    assert run.surface(*surface(8), num_contacts=2)
    assert ev.shapes == [2] and ev.scored == [(0.5, ("scores of", 8)), (0.8, ("scores of", 8))]
    # an estimator that holds fewer contacts than touches (it refused one) is answered in order
    ev = FakeEvaluator([([], ""), ([0.8], "goal")], EvalConfig(shape_every_contacts=1))
    run = RunControl(ev)  # type: ignore[arg-type]
    assert touch(run, 1 * S_NS) and touch(run, 2 * S_NS)
    assert not run.surface(*surface(3), num_contacts=0) and ev.shapes == [1]
    assert run.surface(*surface(4), num_contacts=1) and ev.shapes == [1, 2]


def test_a_run_without_a_touch_for_max_idle_s_finishes_as_stalled() -> None:
    ev = FakeEvaluator([([], "")], EvalConfig(max_idle_s=30.0))
    run = RunControl(ev)  # type: ignore[arg-type]
    assert not run.tick(30 * S_NS) and not run.tick(90 * S_NS)  # the first approach has no limit (a far start)
    assert not touch(run, 20 * S_NS)
    assert not run.tick(50 * S_NS)
    assert run.tick(50 * S_NS + 1)
    assert not run.needs_variance
    assert run.surface(*surface(4)) and ev.shapes == [1]  # the end's estimate gets its shape scores
    assert ev.finished == "stalled"
    assert not run.tick(60 * S_NS)  # asked once
    assert not touch(run, 61 * S_NS) and len(ev.touches) == 1
    assert not run.surface(*surface(2)) and ev.shapes == [1]  # answers no request: ignored


def test_a_touch_without_a_fingertip_pose_is_scored_with_the_axis_pointing_down() -> None:
    ev = FakeEvaluator([([], ""), ([], "")])
    run = RunControl(ev)  # type: ignore[arg-type]
    touch(run, S_NS)
    touch(run, 2 * S_NS, axis=np.array([1.0, 0.0, 0.0]))
    np.testing.assert_array_equal(ev.touches[0][4], [0.0, 0.0, -1.0])
    np.testing.assert_array_equal(ev.touches[1][4], [1.0, 0.0, 0.0])


def test_a_last_surface_that_never_comes_ends_the_run_after_the_wait() -> None:
    """The finishing touch asks for the last surface; if none comes within surface_wait_s of simulated
    time (the GPIS node refused the request), the run is overdue, once, and ends without it. A surface
    that comes in time, or a run still going, is never overdue."""
    ev = FakeEvaluator([([0.5, 0.8], "goal")], EvalConfig(surface_wait_s=5.0))
    run = RunControl(ev)  # type: ignore[arg-type]
    assert not run.overdue(100 * S_NS)  # nothing asked for yet
    assert touch(run, 10 * S_NS)
    assert not run.overdue(15 * S_NS)  # 5 s: still waiting
    assert run.overdue(15 * S_NS + 1)
    assert not run.overdue(16 * S_NS)  # once
    assert ev.scored == []  # the milestones keep no RMSE
    served = RunControl(FakeEvaluator([([0.8], "goal")], EvalConfig(surface_wait_s=5.0)))  # type: ignore[arg-type]
    assert touch(served, 10 * S_NS)
    assert served.surface(*surface(4))
    assert not served.overdue(100 * S_NS)
    stalled = RunControl(FakeEvaluator([([], "")], EvalConfig(max_idle_s=30.0, surface_wait_s=5.0)))  # type: ignore[arg-type]
    assert not touch(stalled, S_NS)
    assert stalled.tick(32 * S_NS)  # stalled: asks for the last surface
    assert not stalled.overdue(37 * S_NS) and stalled.overdue(38 * S_NS)


def test_a_checkpoints_late_surface_does_not_stand_in_for_the_last_one() -> None:
    """The checkpoint's surface comes after the finishing touch and answers only the checkpoint: the run
    still waits for its last surface, and is overdue surface_wait_s after the finishing touch."""
    ev = FakeEvaluator([([], ""), ([0.8], "goal")], EvalConfig(shape_every_contacts=1, surface_wait_s=5.0))
    run = RunControl(ev)  # type: ignore[arg-type]
    assert touch(run, 1 * S_NS) and touch(run, 2 * S_NS)
    assert not run.surface(*surface(3), num_contacts=1)
    assert not run.overdue(7 * S_NS)  # 5 s after the finishing touch at 2 s: still waiting
    assert run.overdue(7 * S_NS + 1)
