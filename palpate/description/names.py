"""Matching the joint and link names a message carries to the names a model expects.

A JointState or JointCommand names its joints, a ContactSet the link of each contact; the simulator
and the mapper each hold their own order (the hand description's). ``match_names`` says where each
expected name stands in a message and which names are missing, unknown or repeated, so that a node
can reorder the message's values and refuse (or report) what does not fit.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class NameMatch:
    """Where each wanted name stands among the given names.

    index: (len(wanted),) position of each wanted name in ``given`` (the last, where ``given``
      repeats it), -1 where it is absent.
    missing: the wanted names absent from ``given``, in wanted's order (repeats kept).
    unknown: the given names nobody wants, in given's order, once each.
    repeated: the names ``given`` holds more than once, in given's order.
    """

    index: NDArray[np.intp]
    missing: tuple[str, ...]
    unknown: tuple[str, ...]
    repeated: tuple[str, ...]

    @property
    def found(self) -> NDArray[np.bool_]:
        """(len(wanted),) True where the wanted name is in ``given``."""
        return np.asarray(self.index >= 0)


def match_names(wanted: Sequence[str], given: Sequence[str]) -> NameMatch:
    """Where each of ``wanted`` stands in ``given``; see NameMatch.

    Values that come in given's order are put in wanted's order by ``values[match.index]``
    (when nothing is missing).
    """
    position = {name: i for i, name in enumerate(given)}
    wanted_set = set(wanted)
    return NameMatch(
        index=np.array([position.get(name, -1) for name in wanted], dtype=np.intp),
        missing=tuple(name for name in wanted if name not in position),
        unknown=tuple(name for name in position if name not in wanted_set),
        repeated=tuple(name for name, count in Counter(given).items() if count > 1),
    )
