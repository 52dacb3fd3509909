"""match_names: positions, missing, unknown and repeated names."""

from __future__ import annotations

import numpy as np

from palpate.description.names import match_names


def test_positions_of_the_wanted_names_reorder_the_values() -> None:
    given = ["dip", "thumb", "pip", "mcp"]
    values = np.array([4.0, 9.0, 3.0, 1.0])
    match = match_names(["mcp", "pip", "dip"], given)
    assert match.index.dtype == np.intp
    np.testing.assert_array_equal(match.index, [3, 2, 0])
    np.testing.assert_array_equal(values[match.index], [1.0, 3.0, 4.0])
    assert match.missing == () and match.repeated == ()
    assert match.unknown == ("thumb",)
    np.testing.assert_array_equal(match.found, [True, True, True])


def test_missing_unknown_and_repeated_names_are_reported() -> None:
    match = match_names(["a", "b", "c", "b"], ["x", "c", "x", "a", "y"])
    np.testing.assert_array_equal(match.index, [3, -1, 1, -1])
    np.testing.assert_array_equal(match.found, [True, False, True, False])
    assert match.missing == ("b", "b")
    assert match.unknown == ("x", "y")
    assert match.repeated == ("x",)
    assert match_names(["c"], ["c", "c"]).index.tolist() == [1]  # the last of a repeated name


def test_empty_sequences() -> None:
    empty = match_names([], ["a"])
    assert empty.index.shape == (0,) and empty.unknown == ("a",)
    nothing = match_names(["a"], [])
    assert nothing.index.tolist() == [-1] and nothing.missing == ("a",) and nothing.unknown == ()
