"""The demo's printed metrics."""

from __future__ import annotations

from palpate.commands.launch import demo_summary


def test_demo_summary_prints_both_milestones_with_the_confident_rmse() -> None:
    milestone = {
        "contacts": 87,
        "travel_cm": 142.66,
        "rotation_deg": 2394.7,
        "rmse_mm": 0.1086,
        "confident_fraction": 0.412,
        "rmse_estimate_to_truth_mm": 13.3,
        "rmse_truth_to_estimate_mm": None,
        "prediction_miss_mm": 1.356,
        "angle_deg": 9.06,
    }
    result = {
        "object": "torus",
        "contacts": 162,
        "coverage": 0.8021,
        "vertex_coverage": 0.82,
        "finished": "goal",
        "milestones": {"50": {**milestone, "reached": True}, "80": {**milestone, "reached": False}},
    }
    lines = demo_summary(result).splitlines()
    assert lines[0] == "[demo] torus: 162 contacts, coverage 80.2 % (by area; 82.0 % of vertices), finished: goal"
    assert "50 % coverage reached: 87 contacts, travel 142.7 cm" in lines[1]
    assert "surface RMSE 0.11 mm over the confident 41 % of the estimate" in lines[1]
    assert "truth->estimate n/a" in lines[1]
    assert "80 % coverage NOT reached" in lines[2]
