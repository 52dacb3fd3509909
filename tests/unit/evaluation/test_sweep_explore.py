"""palpate sweep explore's rows: one per setting and strategy, end figures over every run, --only checked."""

from __future__ import annotations

import math
from typing import Any

import pytest

from palpate.errors import ConfigError
from palpate.evaluation.sweep_explore import SETTINGS, check_sets, chosen_settings, summarise, table


def run(strategy: str, reached: bool, fscore_end: float, travel_end: float) -> dict[str, Any]:
    at80 = {"reached": reached, "rmse_mm": 0.5, "rmse_symmetric_mm": 0.7, "fscore_2mm": 0.95, "travel_cm": 100.0}
    return {
        "strategy": strategy,
        "milestones": {"80": {**at80, "prediction_miss_mm": 2.0}},
        "contacts": 50,
        "coverage": 0.8 if reached else 0.3,
        "plan_ms": 10.0,
        "cpu_s": 5.0,
        "shape": [{"fscore_2mm": 0.1}, {"fscore_2mm": fscore_end}],
        "touches": [{"travel_cm": 1.0}, {"travel_cm": travel_end}],
    }


def test_a_run_kept_from_80_percent_still_shows_its_end_figures() -> None:
    """An outside audit: 5 cm of contact noise kept the run from 80 % and the row showed only dashes."""
    noisy = summarise(SETTINGS[0], "igef", [run("igef", False, 0.01, 1089.0)])
    assert noisy["completed"] == 0 and math.isnan(noisy["fscore_2mm"]) and math.isnan(noisy["travel_cm"])
    assert noisy["fscore_2mm_end"] == 0.01 and noisy["travel_cm_end"] == 1089.0 and noisy["coverage"] == 0.3
    assert noisy["strategy"] == "igef"
    both = summarise(SETTINGS[0], "gpv", [run("gpv", True, 0.9, 120.0), run("gpv", False, 0.5, 300.0)])
    assert both["completed"] == 1 and both["fscore_2mm"] == 0.95 and both["fscore_2mm_end"] == pytest.approx(0.7)
    text = table([noisy, both])
    assert "| default | - | igef | 0/1 |" in text and "| default | - | gpv | 1/2 |" in text
    assert "| 30.0 | 0.010 | 1089.0 |" in text  # coverage, F-score and travel at the end


def test_only_names_settings_or_knobs_and_refuses_a_word_that_matches_none() -> None:
    assert chosen_settings("contact noise")[0].name == "default"
    assert len(chosen_settings("contact noise")) == 1 + sum(s.knob == "contact noise" for s in SETTINGS)
    assert chosen_settings("") == list(SETTINGS)
    with pytest.raises(ConfigError, match=r"--only 'bogus' matches no setting; .*knobs: \["):
        chosen_settings("kernel,bogus")


def test_sweep_slam_checks_its_settings_before_recording_anything() -> None:
    """An outside audit: a K whose maps could not fit failed on the worker, after the recording, and was
    retried; a repeated value failed with a message about run keys."""
    from palpate.evaluation.sweep_slam import check_settings

    with pytest.raises(ConfigError, match=r"n_particles = 100000000000 .* GiB"):
        check_settings([10, 100_000_000_000], [2.0])
    with pytest.raises(ConfigError, match=r"--resolutions-mm repeats a value: \[4.0, 4.0\]"):
        check_settings([10], [4.0, 4.0])
    check_settings([1, 10, 100], [1.0, 2.0, 4.0])  # the sweep's defaults fit


def test_sweep_slam_refuses_cells_the_region_cannot_hold_and_notes_fine_grids(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A cell larger than a quarter of the mapped region gave NaN scores with exit 0; a 0.1 mm grid ran
    for hours with a progress bar that did not move."""
    from palpate.evaluation.sweep_slam import check_settings

    with pytest.raises(ConfigError, match=r"cells of 30 mm leave fewer than 4 across the 90 mm region.*22.5 mm"):
        check_settings([1], [30.0])
    check_settings([1], [22.5, 1.0])
    assert capsys.readouterr().err == ""
    check_settings([1], [0.1])
    assert "note: --resolutions-mm 0.1 gives about 729,000,000 cells per map" in capsys.readouterr().err


def test_a_set_of_a_knob_the_sweep_turns_is_refused_by_name() -> None:
    """An outside audit: --set noise.position_sigma_m with the noise settings failed on a repeated run key."""
    noise = chosen_settings("contact noise")
    with pytest.raises(ConfigError, match=r"--set noise.position_sigma_m sets the knob that setting 'contact position"):
        check_sets(noise, {"noise.position_sigma_m": 0.0005})
    check_sets(noise, {"gpis.gp.kernel": "gaussian"})  # another knob: for every row
