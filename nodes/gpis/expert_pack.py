"""The local experts' contacts and weights in one pair of arrays, for ``LocalGPIS``' compiled loops.

Every query contracts many experts at once (``local_kernels``), which wants the contacts P (T, 3) and
weights alpha A (T, 4) of all experts concatenated. Rebuilding that concatenation after each touch
costs O(experts) in Python (thousands of experts on a large object), so the pack is updated in place:
slot 0 is the far field, each expert gets the next slot when it appears (slots never move), and a
changed expert's rows are appended at the end, its old rows left as garbage until the garbage
exceeds the live rows and the arrays are compacted. A touch thus costs the rows of the experts it
changed, amortised, whatever the history.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from palpate.nodes.gpis.core import GPIS

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Slot of the far-field expert.
FAR_SLOT = 0


class ExpertPack:
    """Slots of the experts (0: far field) with their rows in the packed arrays."""

    def __init__(self) -> None:
        self.experts: list[GPIS | None] = [None]  # slot -> expert; slot 0 (far field) None until it exists
        self._slot_of: dict[int, int] = {}  # key -> slot of the experts in the table
        self._dirty: set[int] = set()
        self._table: tuple[IntArray, IntArray] | None = None
        self._P = np.zeros((0, 3))
        self._A = np.zeros((0, 4))
        self._used = 0  # rows written, garbage included
        self._live = 0  # rows of the experts' current segments
        self.starts = np.zeros(1, dtype=np.int64)
        self.ends = np.zeros(1, dtype=np.int64)

    def set(self, key: int | None, expert: GPIS) -> None:
        """Expert `key` (None: the far field) is new or has changed: its rows are rewritten on next use."""
        if key is None:
            slot = FAR_SLOT
        elif (found := self._slot_of.get(key)) is not None:
            slot = found
        else:
            slot = self._slot_of[key] = len(self.experts)
            self.experts.append(expert)
            self._table = None
        self.experts[slot] = expert
        self._dirty.add(slot)

    def drop(self, key: int) -> None:
        """Expert `key` holds no contact any more: out of the table, so that its weight goes to the far
        field (its slot stays empty; a later ``set`` of the key takes a new one)."""
        slot = self._slot_of.pop(key)
        self.experts[slot] = None
        self._dirty.add(slot)
        self._table = None

    def table(self) -> tuple[IntArray, IntArray]:
        """The experts' keys sorted (e,) and the slot of each (e,) (``local_kernels.blend_pairs``' table)."""
        if self._table is None:
            keys = np.fromiter(self._slot_of.keys(), dtype=np.int64, count=len(self._slot_of))
            slots = np.fromiter(self._slot_of.values(), dtype=np.int64, count=len(self._slot_of))
            order = np.argsort(keys, kind="stable")
            self._table = (keys[order], slots[order])
        return self._table

    def arrays(self) -> tuple[FloatArray, FloatArray, IntArray, IntArray]:
        """(P (T, 3), A (T, 4), starts (s,), ends (s,)): slot s owns rows starts[s]:ends[s]."""
        if self._dirty:
            self._refresh()
        return self._P, self._A, self.starts, self.ends

    def _refresh(self) -> None:
        slots = len(self.experts)
        if len(self.starts) < slots:
            grow = slots - len(self.starts)
            self.starts = np.concatenate([self.starts, np.zeros(grow, dtype=np.int64)])
            self.ends = np.concatenate([self.ends, np.zeros(grow, dtype=np.int64)])
        dirty = sorted(self._dirty)
        self._dirty.clear()
        segments = [(s, *self._weights(s)) for s in dirty]
        new_rows = sum(len(P) for _, P, _ in segments)
        self._live += new_rows - int(np.sum(self.ends[dirty] - self.starts[dirty]))
        if self._used + new_rows > 2 * self._live + 256:  # mostly garbage: compact, O(T) amortised
            segments = [(s, *self._weights(s)) for s in range(slots)]
            self._used = 0
            new_rows = self._live
        self._reserve(self._used + new_rows)
        for s, P, A in segments:
            start, end = self._used, self._used + len(P)
            self._P[start:end], self._A[start:end] = P, A
            self.starts[s], self.ends[s] = start, end
            self._used = end

    def _weights(self, slot: int) -> tuple[FloatArray, FloatArray]:
        expert = self.experts[slot]
        return expert.residual_weights() if expert is not None else (np.zeros((0, 3)), np.zeros((0, 4)))

    def _reserve(self, rows: int) -> None:
        if rows <= len(self._P):
            return
        cap = max(rows, int(1.5 * len(self._P)), 256)
        P, A = np.zeros((cap, 3)), np.zeros((cap, 4))
        P[: self._used], A[: self._used] = self._P[: self._used], self._A[: self._used]
        self._P, self._A = P, A
