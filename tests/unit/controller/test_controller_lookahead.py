"""The look-ahead on the curve: it grows at a sharp bend and on a short curve, instead of oscillating."""

from __future__ import annotations

import numpy as np

from palpate.nodes.controller.trajectory import ControllerConfig, ControllerState, TrajectoryController

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


def short_hop(hop_m: float, lookahead_one_step: bool) -> tuple[float, float, float]:
    """A hop of hop_m along a plane (z = 0, centre at the tip radius) in 10 ms steps at 5 cm/s: the curve's
    length, the path travelled to the plane and the angle between the last step and the normal, degrees."""
    ctrl = TrajectoryController(ControllerConfig(lookahead_one_step=lookahead_one_step))
    r = np.array([0.0, 0.0, 0.008])
    P = ctrl.start(r, np.array([0.0, 0.0, -1.0]), R_DOWN, np.array([hop_m, 0.0, 0.008]), np.array([0.0, 0.0, 1.0]))
    tau = np.linspace(0.0, 1.0, 4001)[:, None]
    curve = (1 - tau) ** 3 * P[0] + 3 * (1 - tau) ** 2 * tau * P[1] + 3 * (1 - tau) * tau**2 * P[2] + tau**3 * P[3]
    path = 0.0
    for _ in range(500):
        v, _ = ctrl.command(r, R_DOWN)
        step = v * 0.01
        path += float(np.linalg.norm(step))
        r = r + step
        if r[2] < 0.008 and path > 0.002:  # the fingertip sphere reaches the plane
            break
    angle = float(np.degrees(np.arccos(-step[2] / np.linalg.norm(step))))
    return float(np.linalg.norm(np.diff(curve, axis=0), axis=1).sum()), path, angle


def test_a_short_curve_is_followed_not_zigzagged_about() -> None:
    # Delta tau = 0.02 of a 6 mm curve is 0.12 mm, a quarter of one 0.5 mm step: looking that far ahead
    # the fingertip overshoots every tick and zigzags; looking one step ahead it follows the curve
    for hop in (0.003, 0.005, 0.008):
        length, path, angle = short_hop(hop, lookahead_one_step=True)
        assert path < length + 0.001, (hop, length, path)
        assert angle < 15.0, (hop, angle)
        length, path, angle = short_hop(hop, lookahead_one_step=False)
        assert path > 1.2 * length and angle > 45.0, (hop, length, path, angle)
    # a long curve is followed either way
    for one_step in (True, False):
        length, path, angle = short_hop(0.03, lookahead_one_step=one_step)
        assert path < length + 0.001 and angle < 5.0
