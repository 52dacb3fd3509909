"""Coarse control steps through a sharp bend: the look-ahead grows instead of oscillating in place."""

from __future__ import annotations

import numpy as np

from palpate.nodes.controller.core import ControllerConfig, ControllerState, TrajectoryController

R_DOWN = np.diag([1.0, -1.0, -1.0])  # fingertip pokes along -z
# An Eq. 15 curve the planner produced on the YCB golf ball: up 7 mm, then a sharp turn down.
CURVE = np.array(
    [
        [0.00490043, -0.0049867, 0.04945015],
        [0.00686145, -0.00526801, 0.0568191],
        [0.00268268, -0.00477262, 0.01904517],
        [0.00304437, -0.00421457, 0.02664675],
    ]
)


def test_tau_keeps_advancing_through_a_sharp_bend_with_coarse_steps() -> None:
    # 10 ms control steps at 5 cm/s (0.5 mm): at the bend T(tau + 0.02) lies closer than one step;
    # without the longer look-ahead the fingertip jumps between two points with tau stuck at 0.109
    beta = float(np.linalg.norm(CURVE[0] - CURVE[3])) / 3.0
    v_n, t_n = -(CURVE[1] - CURVE[0]) / beta, (CURVE[2] - CURVE[3]) / beta
    ctrl = TrajectoryController(ControllerConfig())
    r = CURVE[0].copy()
    np.testing.assert_allclose(ctrl.start(r, v_n, R_DOWN, CURVE[3], t_n), CURVE, atol=1e-8)
    taus = []
    for _ in range(200):
        v, _ = ctrl.command(r, R_DOWN)
        if ctrl.state is not ControllerState.APPROACH:
            break
        r = r + v * 0.01
        taus.append(ctrl.tau)
    assert taus[10] > 0.2, f"tau stalled at {taus[10]:.3f}"
    assert taus[-1] > 0.95
