"""The hand description: the packaged file against docs/hand_model.md, and the checks of the loader."""

from __future__ import annotations

import copy
import math
import re
from pathlib import Path
from typing import Any

import pytest
import yaml

from palpate.description import as_written, load_hand, parse_hand
from palpate.errors import ConfigError
from palpate.paths import REPO_ROOT

HAND_YAML = REPO_ROOT / "palpate" / "description" / "hand.yaml"
DOC = REPO_ROOT / "docs" / "hand_model.md"


def _data() -> dict[str, Any]:
    data = yaml.safe_load(HAND_YAML.read_text())
    assert isinstance(data, dict)
    return data


def _doc_rows(header: str) -> dict[str, list[str]]:
    """Cells of the markdown table whose header line starts with ``header``, by first cell."""
    lines = DOC.read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(header))
    rows = {}
    for line in lines[start + 2 :]:
        if not line.startswith("|"):
            break
        cells = [c.strip().strip("`") for c in line.strip("|").split("|")]
        rows[cells[0]] = cells[1:]
    return rows


def test_the_packaged_hand_has_21_joints_in_model_order() -> None:
    hand = load_hand()
    assert hand.long_fingers == ("index", "middle", "ring", "little")
    names = hand.joint_names()
    assert len(names) == 21 and names[:4] == ["index_mcp_abd", "index_mcp_flex", "index_pip", "index_dip"]
    assert names[16:] == ["thumb_cmc_flex", "thumb_cmc_abd", "thumb_cmc_rot", "thumb_mcp", "thumb_ip"]
    assert hand.radius_m() == 0.008 and hand.radius_m(2.0) == 0.016
    assert load_hand() is load_hand()  # read once
    assert all(j.source for d in hand.digits for j in d.joints)


def test_lengths_and_ranges_are_the_ones_docs_hand_model_lists() -> None:
    hand = load_hand()
    lengths = _doc_rows("| digit  | metacarpal (mm)")
    assert set(lengths) == {d.name for d in hand.digits}
    for name, cells in lengths.items():
        assert hand.digit(name).lengths_mm == tuple(float(c) for c in cells if c != "-"), name
    ranges = {**_doc_rows("| joint (per long finger"), **_doc_rows("| thumb joint")}
    for digit in hand.digits:
        for joint in digit.joints:
            key = f"thumb_{joint.name}" if digit.name == "thumb" else f"f_{joint.name}"
            lo, hi = (float(v) for v in re.findall(r"-?\d+", ranges[key][1]))
            assert joint.range_deg == (lo, hi), key


def test_palm_layout_gives_the_documented_mcp_positions() -> None:
    layout = _doc_rows("| digit  | base x (mm)")
    for name in load_hand().long_fingers:
        expected = [float(v) for v in re.findall(r"-?\d+\.\d", layout[name][3])]
        mcp = load_hand().digit(name).first_joint_m()
        assert [round(1e3 * v, 1) for v in mcp[:2]] == expected and mcp[2] == 0.0


def test_a_hand_file_can_be_given_by_path(tmp_path: Path) -> None:
    data = _data()
    data["long_fingers"]["index"]["lengths_mm"] = [70.0, 40.0, 22.0, 16.0]
    path = tmp_path / "hand.yaml"
    path.write_text(yaml.safe_dump(data))
    assert load_hand(path).digit("index").lengths_m() == (0.07, 0.04, 0.022, 0.016)
    with pytest.raises(ConfigError, match="cannot read"):
        load_hand(tmp_path / "absent.yaml")
    path.write_text("segment_radius_mm: [")
    with pytest.raises(ConfigError, match="invalid YAML"):
        load_hand(path)


def _set(data: dict[str, Any], path: str, value: Any) -> None:
    *parents, last = path.split(".")
    node: Any = data
    for key in parents:
        node = node[int(key)] if isinstance(node, list) else node[key]
    if value is KeyError:
        del node[last]
    elif isinstance(node, list):
        node[int(last)] = value
    else:
        node[last] = value


NEW_FINGER = {"lengths_mm": [1, 2, 3, 4], "metacarpal_base_mm": [0, 0], "metacarpal_yaw_deg": 0}


@pytest.mark.parametrize(
    ("path", "value", "message", "key"),
    [
        ("colour", "pink", "hand.colour: unknown key 'colour'; known keys: actuation, finger_mount, long", "colour"),
        (
            "finger_mount.finger",
            "thumb",
            "hand: finger_mount.finger: 'thumb' is not a long finger",
            "finger_mount.finger",
        ),
        ("segment_radius_mm", KeyError, "hand: missing required key 'segment_radius_mm' (float)", ""),
        (
            "segment_radius_mm",
            -8.0,
            "hand.segment_radius_mm: expected a finite number > 0, got -8.0",
            "segment_radius_mm",
        ),
        (
            "long_fingers.ring.lengths_mm",
            [58.0, math.nan, 25.0, 17.0],
            "hand.long_fingers.ring.lengths_mm[1]: expected a finite number > 0, got nan",
            "long_fingers.ring.lengths_mm.1",
        ),
        (
            "long_fingers.ring.lengths_mm",
            [58.0, 41.0, 25.0],
            "hand: long_fingers.ring.lengths_mm: 3 lengths; give one per segment ['metacarpal', ",
            "long_fingers.ring.lengths_mm",
        ),
        (
            "long_fingers.thumb",
            NEW_FINGER,
            "hand: long_fingers: ['index', 'middle', 'ring', 'little', 'thumb']: name",
            "long_fingers",
        ),
        (
            "long_fingers.ring",
            {"lengths_mm": [1, 2, 3, 4]},
            "hand.long_fingers.ring: missing required key 'metacarpal_base_mm'",
            "long_fingers.ring",
        ),
        (
            "long_finger_joints.2.range_deg",
            [100, 0],
            "hand.long_finger_joints[2]: range_deg = [100.0, 0.0]: empty range; give [lower, upper] with lower < upper",
            "long_finger_joints.2.range_deg",
        ),
        (
            "long_finger_joints.1.axis",
            [0, 2, 0],
            "hand.long_finger_joints[1]: axis = [0.0, 2.0, 0.0]: expected a unit vector",
            "long_finger_joints.1.axis",
        ),
        (
            "long_finger_joints.1.axis",
            [0, 1],
            "hand.long_finger_joints[1].axis: expected 3 items, got [0, 1]",
            "long_finger_joints.1.axis",
        ),
        (
            "long_finger_joints.1.source",
            KeyError,
            "hand.long_finger_joints[1]: missing required key 'source'",
            "long_finger_joints.1",
        ),
        (
            "long_finger_joints.1.segment",
            "palm",
            "hand: long_finger_joints[1].segment: 'palm' is not one of the segments ['metacarpal', ",
            "long_finger_joints.1.segment",
        ),
        (
            "long_finger_joints.0.segment",
            "metacarpal",
            "hand: long_finger_joints: the first segment (the metacarpal) must have no joint",
            "long_finger_joints",
        ),
        (
            "long_finger_joints.3.segment",
            "proximal",
            "hand: long_finger_joints: list the joints proximal to distal, each name once",
            "long_finger_joints",
        ),
        (
            "long_finger_segments",
            ["metacarpal", "proximal", "proximal", "distal"],
            "hand: long_finger_segments: ['metacarpal', 'proximal', 'proximal', 'distal']: give each segment a name",
            "long_finger_segments",
        ),
        ("long_finger_joints", [], "hand.long_finger_joints: expected a non-empty list, got []", "long_finger_joints"),
        (
            "thumb.joints.0.segment",
            "proximal",
            "hand.thumb: joints: list the joints proximal to distal",
            "thumb.joints",
        ),
        (
            "thumb.lengths_mm",
            [46.0, 31.0],
            "hand.thumb: lengths_mm: 2 lengths; give one per segment",
            "thumb.lengths_mm",
        ),
        (
            "actuation.kp_nm_per_rad",
            True,
            "hand.actuation.kp_nm_per_rad: expected a finite number > 0, got True",
            "actuation.kp_nm_per_rad",
        ),
        (
            "actuation.density_kg_m3",
            math.inf,
            "hand.actuation.density_kg_m3: expected a finite number > 0, got inf",
            "actuation.density_kg_m3",
        ),
        (
            "thumb.rest_ypr_deg",
            [40, 20],
            "hand.thumb.rest_ypr_deg: expected 3 items, got [40, 20]",
            "thumb.rest_ypr_deg",
        ),
    ],
)
def test_a_bad_hand_file_is_refused_naming_the_key(path: str, value: Any, message: str, key: str) -> None:
    data = copy.deepcopy(_data())
    _set(data, path, value)
    with pytest.raises(ConfigError) as info:
        parse_hand(data)
    assert str(info.value).startswith(message), str(info.value)
    assert info.value.path == tuple(int(k) if k.isdigit() else k for k in key.split(".") if k)


def test_a_bad_hand_file_is_refused_naming_its_line(tmp_path: Path) -> None:
    text = HAND_YAML.read_text()
    lines = text.splitlines()
    ring = next(i for i, line in enumerate(lines) if line.lstrip().startswith("ring:")) + 1
    pip = next(i for i, line in enumerate(lines) if "{name: pip," in line) + 1
    path = tmp_path / "hand.yaml"
    path.write_text(text.replace("ring: {lengths_mm: [58.00, 41.37,", "ring: {lengths_mm: [58.00, .nan,"))
    with pytest.raises(
        ConfigError, match=rf"^{path}:{ring}: hand.long_fingers.ring.lengths_mm\[1\]: expected a finite"
    ):
        load_hand(path)
    path.write_text(text.replace("range_deg: [0, 100]", "range_deg: [100, 0]"))
    with pytest.raises(ConfigError, match=rf"^{path}:{pip}: hand.long_finger_joints\[2\]: range_deg = \[100.0, 0.0\]"):
        load_hand(path)


def test_a_thumb_whose_first_segment_has_no_joint_is_refused() -> None:
    data = _data()
    data["thumb"]["joints"] = [j for j in data["thumb"]["joints"] if j["segment"] != "metacarpal"]
    with pytest.raises(ConfigError, match=r"hand.thumb: joints: the thumb's first segment .* must have a joint"):
        parse_hand(data)


def test_unknown_digit_lists_the_digits() -> None:
    with pytest.raises(ConfigError, match="use one of index, middle, ring, little, thumb"):
        load_hand().digit("pinky")


def test_as_written_rounds_to_the_mjcf_precision() -> None:
    assert as_written(64.6 / 1000) == 0.0646 != 64.6 / 1000
    assert as_written(0.1234567891234) == 0.123456789
    assert as_written(as_written(1 / 3)) == as_written(1 / 3)
