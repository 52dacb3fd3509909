"""ContactAgreement: contacts that pass each message's checks but disagree with the fingertip are named once."""

from __future__ import annotations

import numpy as np
import pytest

from palpate.nodes.controller.contact_check import JUDGED_SETS, ContactAgreement

RADIUS = 0.008
CENTRE = np.array([0.0, 0.0, 0.05])


def _contacts(rng: np.random.Generator, *, inward: bool = False, offset_m: float = 0.0, noise_m: float = 0.0):
    """Three contacts on the fingertip's lower half, outward normals (the object's, pointing at the centre),
    with position noise; inward flips the normals, offset_m moves the points off the fingertip along x."""
    directions = np.array([[0.0, 0.0, -1.0], [0.3, 0.0, -1.0], [0.0, -0.3, -1.0]])
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    positions = CENTRE + RADIUS * directions + rng.normal(0.0, noise_m, (3, 3)) + [offset_m, 0.0, 0.0]
    normals = -directions if not inward else directions
    return positions, normals


def _verdict(agreement: ContactAgreement, sets) -> list[str]:
    return [note for positions, normals in sets if (note := agreement.read(CENTRE, positions, normals))]


@pytest.mark.parametrize("noise_m", [0.0, 0.002])
def test_contacts_on_the_fingertip_with_outward_normals_raise_no_note(noise_m: float) -> None:
    rng = np.random.default_rng(0)
    assert _verdict(ContactAgreement(RADIUS), [_contacts(rng, noise_m=noise_m) for _ in range(3 * JUDGED_SETS)]) == []


def test_inward_normals_are_named_once_after_the_judged_sets() -> None:
    rng = np.random.default_rng(0)
    agreement = ContactAgreement(RADIUS)
    empty = (np.zeros((0, 3)), np.zeros((0, 3)))
    sets = [empty] + [_contacts(rng, inward=True) for _ in range(3 * JUDGED_SETS)]
    notes = _verdict(agreement, sets)
    assert len(notes) == 1  # once, and sets without contacts do not count
    assert notes[0].startswith(f"in {JUDGED_SETS} of the first {JUDGED_SETS} contact sets the normals point into")
    assert "must point out of the object" in notes[0] and "lie more than" not in notes[0]


def test_points_off_the_fingertip_are_named_with_the_radius() -> None:
    """A driver's contacts in the fingertip's frame lay 5 cm from it and passed the 0.1 m reach check."""
    rng = np.random.default_rng(0)
    notes = _verdict(ContactAgreement(RADIUS), [_contacts(rng, offset_m=0.05) for _ in range(JUDGED_SETS)])
    assert len(notes) == 1 and "lie more than 0.026 m from the fingertip's centre" in notes[0]
    assert "world frame" in notes[0] and "normals" not in notes[0]


def test_a_minority_of_bad_sets_and_a_point_probes_normals_are_not_named() -> None:
    rng = np.random.default_rng(0)
    bad = JUDGED_SETS // 2  # half is not most
    sets = [_contacts(rng, inward=True) for _ in range(bad)] + [_contacts(rng) for _ in range(JUDGED_SETS - bad)]
    assert _verdict(ContactAgreement(RADIUS), sets) == []
    point_probe = [(np.repeat(CENTRE[None], 2, axis=0), -np.eye(3)[:2]) for _ in range(JUDGED_SETS)]
    assert _verdict(ContactAgreement(0.0), point_probe) == []
