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


@pytest.mark.parametrize(
    ("path", "value", "message"),
    [
        ("colour", "pink", "unknown key 'colour'"),
        ("segment_radius_mm", KeyError, "missing key 'segment_radius_mm'"),
        ("segment_radius_mm", -8.0, "positive"),
        ("long_fingers.ring.lengths_mm", [58.0, math.nan, 25.0, 17.0], "finite"),
        ("long_fingers.ring.lengths_mm", [58.0, 41.0, 25.0], "list of 4 numbers"),
        ("long_fingers.thumb", {"lengths_mm": [1, 2, 3, 4]}, "not 'thumb'"),
        ("long_finger_joints.2.range_deg", [100, 0], "lower < upper"),
        ("long_finger_joints.1.axis", [0, 2, 0], "unit vector"),
        ("long_finger_joints.1.segment", "palm", "not one of the segments"),
        ("long_finger_joints.0.segment", "metacarpal", "must have no joint"),
        ("long_finger_joints.3.segment", "proximal", "proximal to distal"),
        ("thumb.joints.0.segment", "proximal", "proximal to distal"),
        ("actuation.kp_nm_per_rad", True, "finite number"),
        ("thumb.rest_ypr_deg", [40, 20], "list of 3 numbers"),
    ],
)
def test_a_bad_hand_file_is_refused_naming_the_key(path: str, value: Any, message: str) -> None:
    data = copy.deepcopy(_data())
    _set(data, path, value)
    with pytest.raises(ConfigError, match=re.escape(message)):
        parse_hand(data, "hand.yaml")


def test_a_thumb_whose_first_segment_has_no_joint_is_refused() -> None:
    data = _data()
    data["thumb"]["joints"] = [j for j in data["thumb"]["joints"] if j["segment"] != "metacarpal"]
    with pytest.raises(ConfigError, match="must have a joint"):
        parse_hand(data)


def test_unknown_digit_lists_the_digits() -> None:
    with pytest.raises(ConfigError, match="use one of index, middle, ring, little, thumb"):
        load_hand().digit("pinky")


def test_as_written_rounds_to_the_mjcf_precision() -> None:
    assert as_written(64.6 / 1000) == 0.0646 != 64.6 / 1000
    assert as_written(0.1234567891234) == 0.123456789
    assert as_written(as_written(1 / 3)) == as_written(1 / 3)
