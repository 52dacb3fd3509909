"""Descriptions of the robot that every node reads as data (as ROS nodes read a URDF)."""

from palpate.description.hand import (
    MJCF_SIGNIFICANT_DIGITS,
    Actuation,
    DefaultMount,
    Digit,
    HandDescription,
    Joint,
    as_written,
    load_hand,
    mount_fact,
    parse_hand,
)

__all__ = [
    "MJCF_SIGNIFICANT_DIGITS",
    "Actuation",
    "DefaultMount",
    "Digit",
    "HandDescription",
    "Joint",
    "as_written",
    "load_hand",
    "mount_fact",
    "parse_hand",
]
