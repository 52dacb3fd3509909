"""palpate.inputs: each check accepts what a sane sender sends, unchanged, and refuses garbage naming the field."""

from __future__ import annotations

import re

import numpy as np
import pytest

from palpate.errors import InputError, PalpateError
from palpate.inputs import (
    MAX_COORDINATE_M,
    Accumulated,
    all_finite,
    bounded,
    contact_arrays,
    coordinates,
    fingertip_pose,
    per_vertex,
    select_named,
    triangle_mesh,
    unique_names,
    unit_or_zero,
    unit_or_zero_rows,
    unit_quaternion,
    unit_vectors,
    within_reach,
)


def test_input_error_names_field_and_reason() -> None:
    error = InputError("quaternion_wxyz", "norm 0")
    assert isinstance(error, PalpateError)
    assert (error.field, error.reason, str(error)) == ("quaternion_wxyz", "norm 0", "quaternion_wxyz: norm 0")


def test_coordinates_pass_unchanged_up_to_the_bound() -> None:
    a = np.array([[0.1, -0.2, MAX_COORDINATE_M], [np.nextafter(0.0, 1.0), -MAX_COORDINATE_M, 0.0]])
    out = coordinates(a, "positions_m")
    assert out.tobytes() == a.tobytes()
    assert coordinates(np.zeros((0, 3)), "positions_m").shape == (0, 3)


@pytest.mark.parametrize("bad", [1e300, -1e30, np.nextafter(MAX_COORDINATE_M, np.inf)])
def test_coordinates_beyond_the_bound_are_refused(bad: float) -> None:
    with pytest.raises(InputError, match=r"^positions_m: coordinate .* m lies beyond 1000 m of the origin") as info:
        coordinates([[0.0, 0.0, 0.0], [0.0, bad, 0.0]], "positions_m")
    assert info.value.field == "positions_m"


@pytest.mark.parametrize(("bad", "shown"), [(np.inf, "inf"), (-np.inf, "-inf"), (np.nan, "nan")])
def test_coordinates_that_are_not_finite_are_named_so(bad: float, shown: str) -> None:
    with pytest.raises(InputError, match=rf"^positions_m: coordinate {shown} is not finite$"):
        coordinates([[0.0, 0.0, 0.0], [0.0, bad, 1e300]], "positions_m")


def test_nan_means_none_only_where_allowed() -> None:
    assert np.isnan(coordinates([np.nan] * 3, "predicted_contact_m", allow_nan=True)).all()
    with pytest.raises(InputError, match="predicted_contact_m"):
        coordinates([np.nan, np.inf, 0.0], "predicted_contact_m", allow_nan=True)
    with pytest.raises(InputError, match="predicted_contact_m"):
        coordinates([np.nan, 0.0, 0.0], "predicted_contact_m")


def test_bounded_with_and_without_a_lower_bound() -> None:
    assert bounded([-3.0, 3.0], "linear_m_s", 3.0).tolist() == [-3.0, 3.0]
    with pytest.raises(InputError, match=r"^linear_m_s: value 3.5 m/s is outside \[-3, 3\] m/s$"):
        bounded([0.0, 3.5], "linear_m_s", 3.0, "m/s")
    with pytest.raises(InputError, match=r"^forces_n: value -1 N is outside \[0, 10\] N$"):
        bounded([2.0, -1.0], "forces_n", 10.0, "N", lower=0.0)


def test_unit_vectors_within_tolerance_pass_unchanged() -> None:
    n = np.array([[0.0, 0.0, 1.0], [0.6, 0.8, 0.0], [0.0, 1.005, 0.0]])
    assert unit_vectors(n, "normals").tobytes() == n.tobytes()


@pytest.mark.parametrize("row", [[0.0, 0.0, 0.0], [1e-200, 0.0, 0.0], [0.0, 2.0, 0.0], [1e200, 1e200, 0.0]])
def test_non_unit_vectors_are_refused_with_their_norm(row: list[float]) -> None:
    with pytest.raises(InputError, match=r"^normals: row 1 has norm .*, not 1 \(\+-0.01\); send unit vectors"):
        unit_vectors([[1.0, 0.0, 0.0], row], "normals")


def test_unit_quaternion() -> None:
    q = np.array([0.0, 1.0, 0.0, 0.0])
    assert unit_quaternion(q, "quaternion_wxyz").tobytes() == q.tobytes()
    for bad in ([0.0, 0.0, 0.0, 0.0], [1e-200, 0.0, 0.0, 0.0], [1e200, 0.0, 0.0, 0.0], [0.5, 0.5, 0.0, 0.0]):
        with pytest.raises(InputError, match=r"^quaternion_wxyz: norm .* is not that of a unit quaternion"):
            unit_quaternion(bad, "quaternion_wxyz")


def test_fingertip_pose_matches_quat_to_matrix_and_refuses_zero() -> None:
    r, R = fingertip_pose([0.1, 0.2, 0.3], [0.0, 1.0, 0.0, 0.0])
    np.testing.assert_array_equal(r, [0.1, 0.2, 0.3])
    np.testing.assert_allclose(R, np.diag([1.0, -1.0, -1.0]), atol=1e-15)
    with pytest.raises(InputError, match="quaternion_wxyz"):
        fingertip_pose([0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0])
    with pytest.raises(InputError, match="position_m"):
        fingertip_pose([0.0, 1e300, 0.0], [1.0, 0.0, 0.0, 0.0])


def test_contact_arrays() -> None:
    p, n, f = contact_arrays(np.zeros((2, 3)), [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]], [0.0, 3.0])
    assert p.shape == n.shape == (2, 3) and f.tolist() == [0.0, 3.0]
    with pytest.raises(InputError, match=r"^forces_n"):
        contact_arrays(np.zeros((1, 3)), [[0.0, 0.0, 1.0]], [-0.5])
    with pytest.raises(InputError, match=r"^normals"):
        contact_arrays(np.zeros((1, 3)), [[0.0, 0.0, 0.0]], [1.0])


def test_unique_names() -> None:
    assert unique_names(("a", "b"), "names") == ["a", "b"]
    with pytest.raises(InputError, match=r"^names: repeated name\(s\) 'a': each name must appear once"):
        unique_names(["a", "b", "a"], "names")
    with pytest.raises(InputError, match=r"^names: entry 1 is an empty name"):
        unique_names(["a", ""], "names")


def test_select_named_reorders_and_ignores_extra_names() -> None:
    q = select_named(["x", "c", "a", "b"], np.array([9.0, 3.0, 1.0, 2.0]), ["a", "b", "c"], "names")
    assert q.tolist() == [1.0, 2.0, 3.0]


@pytest.mark.parametrize(
    ("names", "reason"),
    [
        ([], "lacks 3 of the 3 names needed: 'a', 'b', 'c'"),
        (["a", "b"], "lacks 1 of the 3 names needed: 'c'"),
        (["a", "b", "c", "a"], r"repeats needed name\(s\) 'a'"),
        (["", "", ""], "lacks 3 of the 3"),
        ([f"j{i}" for i in range(50_000)], "lacks 3 of the 3"),
    ],
    ids=["empty", "subset", "duplicated", "empty-names", "50000-unknown"],
)
def test_select_named_refuses_readings_without_the_joints(names: list[str], reason: str) -> None:
    with pytest.raises(InputError, match=rf"^names: {reason}"):
        select_named(names, np.zeros(len(names)), ["a", "b", "c"], "names")


def test_triangle_mesh() -> None:
    V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    F = np.array([[0, 1, 2], [0, 1, 1], [0, 2, 3]], dtype=np.int32)
    _, F2 = triangle_mesh(V, F, solid=True)
    assert F2.tolist() == [[0, 1, 2], [0, 2, 3]] and F2.dtype == np.int32  # the sliver is dropped
    assert len(triangle_mesh(V, F, solid=False)[1]) == 3  # an estimate keeps its faces as sent
    assert len(triangle_mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int32), solid=False)[1]) == 0
    with pytest.raises(InputError, match=r"^faces: vertex index 4 is outside 0..3"):
        triangle_mesh(V, [[0, 1, 4]], solid=False)
    with pytest.raises(InputError, match=r"^faces: vertex index -1 is outside 0..3"):
        triangle_mesh(V, [[0, 1, -1]], solid=True)
    with pytest.raises(InputError, match=r"^faces: none of the 1 triangles has an area"):
        triangle_mesh(V, [[0, 0, 0]], solid=True)
    with pytest.raises(InputError, match=r"^faces: none of the 1 triangles has an area"):  # squares underflow
        triangle_mesh(np.array([[0.0, 0.0, 0.0], [1e-170, 0.0, 0.0], [0.0, 1e-170, 0.0]]), [[0, 1, 2]], solid=True)
    with pytest.raises(InputError, match=r"^vertices_m: coordinate"):
        triangle_mesh(V * 1e10, F, solid=True)


@pytest.mark.filterwarnings("ignore:invalid value encountered in divide:RuntimeWarning")  # numpy's inf / inf
def test_unit_vectors_and_bounded_of_a_few_values_decide_as_the_numpy_path(monkeypatch: pytest.MonkeyPatch) -> None:
    """The scalar paths of `unit_vectors` and `bounded` accept and refuse exactly what numpy's do (norms at
    the tolerance's edge, values at the bounds, NaN, infinity), and return the values unchanged."""
    from palpate import inputs

    rng = np.random.default_rng(1)
    cases = []
    for shape in [(3,), (4,), (1, 3), (5, 3)]:
        for _ in range(300):
            a = rng.standard_normal(shape)
            a /= np.linalg.norm(a, axis=-1, keepdims=True)
            a *= 1.0 + rng.choice([0.0, 0.00999999, 0.01, 0.0100001, -0.01, -0.5]) * rng.choice([1.0, -1.0])
            if rng.random() < 0.05:
                a.ravel()[0] = rng.choice([np.nan, np.inf, -np.inf, 1e308])
            cases.append(a)

    def outcomes() -> list[tuple[str, str]]:
        out = []
        for a in cases:
            for name, check in (
                ("unit", lambda v: inputs.unit_vectors(v, "n")),
                ("bounded", lambda v: inputs.bounded(v, "b", 1.0, lower=-0.5)),
            ):
                try:
                    got = check(a)
                    out.append((name, got.tobytes().hex()))
                except InputError as exc:
                    out.append((name, str(exc)))
        return out

    few = outcomes()
    monkeypatch.setattr(inputs, "_FEW_VALUES", 0)  # the numpy paths
    assert few == outcomes()


def test_norms_of_a_few_values_take_the_scalar_path_with_numpys_bits(monkeypatch: pytest.MonkeyPatch) -> None:
    from palpate import inputs

    rng = np.random.default_rng(0)
    for shape in [(3,), (4,), (1, 3), (5, 3)]:
        for scale in (1.0, 1e-200, 1e200, 3.7):
            a = rng.standard_normal((50, *shape)) * scale
            a[::7] = 0.0
            few = [inputs._norms(row) for row in a]
            monkeypatch.setattr(inputs, "_FEW_VALUES", 0)  # the numpy path
            reference = [inputs._norms(row) for row in a]
            monkeypatch.undo()
            for got, want in zip(few, reference, strict=True):
                assert got.shape == want.shape and got.tobytes() == want.tobytes()


def test_per_vertex_spreads_values_over_their_vertices_and_refuses_bad_indices() -> None:
    np.testing.assert_array_equal(per_vertex([1.0, 2.0], [0, 3], 4, "variance_vertices", -1.0), [1.0, -1, -1, 2.0])
    assert np.all(np.isnan(per_vertex([], [], 2, "f")))
    for bad in ([1, 1], [2, 1], [0, 4], [-1, 0]):
        with pytest.raises(InputError, match=r"^variance_vertices: must be ascending distinct vertex indices in"):
            per_vertex([1.0, 2.0], bad, 4, "variance_vertices")
    with pytest.raises(InputError, match=r"^f: has 1 indices for 2 values"):
        per_vertex([1.0, 2.0], [0], 4, "f")


@pytest.mark.parametrize(
    "values",
    [[], [0.0, -1.0, 2.5], [1e308, 1e308, 1e308], [1.0, np.nan], [np.inf, 1.0], [-np.inf, np.inf], [1e308] * 100],
)
def test_all_finite_agrees_with_numpy(values: list[float]) -> None:
    array = np.array(values, dtype=np.float64).reshape(-1, 1) if len(values) > 3 else np.array(values, np.float64)
    assert all_finite(array) == bool(np.isfinite(array).all())


def test_many_coordinates_pass_up_to_the_bound_and_nan_anywhere_is_refused() -> None:
    """More than a few values (numpy's path) and NaN where allowed (so not the scalar path): the bound
    itself passes; a NaN in any place of a few values is refused."""
    edge = np.full((7, 3), MAX_COORDINATE_M)
    edge[::2] *= -1.0
    assert coordinates(edge, "positions_m").tobytes() == edge.tobytes()
    assert coordinates([np.nan, MAX_COORDINATE_M, -MAX_COORDINATE_M], "p", allow_nan=True)[1] == MAX_COORDINATE_M
    for at in range(3):
        row = [0.0, 0.0, 0.0]
        row[at] = np.nan
        with pytest.raises(InputError, match=r"^position_m: coordinate nan is not finite$"):
            coordinates(row, "position_m")


def test_many_values_pass_at_either_bound() -> None:
    values = np.array([0.0, 10.0] * 10)
    assert bounded(values, "forces_n", 10.0, "N", lower=0.0).tobytes() == values.tobytes()
    assert bounded(-values, "x", 10.0).tobytes() == (-values).tobytes()


def test_bounded_names_the_value_below_when_values_lie_on_both_sides() -> None:
    with pytest.raises(InputError, match=r"^forces_n: value -1 N is outside \[0, 10\] N$"):
        bounded([20.0, -1.0], "forces_n", 10.0, "N", lower=0.0)


def test_non_unit_vectors_name_the_first_bad_row() -> None:
    with pytest.raises(InputError, match=r"^normals: row 1 has norm 0, not 1"):
        unit_vectors([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 2.0, 0.0]], "normals")


@pytest.mark.parametrize("shape", [(1, 4), (2, 2), (5,)])
def test_a_quaternion_of_another_shape_is_refused(shape: tuple[int, ...]) -> None:
    q = np.zeros(shape)
    q.ravel()[0] = 1.0
    with pytest.raises(
        InputError, match=rf"^quaternion_wxyz: a quaternion has 4 components .* got shape {re.escape(str(shape))}$"
    ):
        unit_quaternion(q, "quaternion_wxyz")


@pytest.mark.filterwarnings("ignore:invalid value encountered in divide:RuntimeWarning")  # numpy's inf / inf
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_a_quaternion_that_is_not_finite_is_refused(bad: float) -> None:
    with pytest.raises(InputError, match=r"^quaternion_wxyz: norm (nan|inf) is not that of a unit quaternion"):
        unit_quaternion([bad, 0.0, 0.0, 1.0], "quaternion_wxyz")


def test_select_named_ignores_a_repeated_name_it_does_not_need() -> None:
    q = select_named(["a", "x", "b", "x", "c"], np.array([1.0, 9.0, 2.0, 9.0, 3.0]), ["a", "b", "c"], "names")
    assert q.tolist() == [1.0, 2.0, 3.0]


def test_a_direction_may_be_a_unit_vector_or_exactly_zero() -> None:
    assert unit_or_zero([0.0, 0.0, 0.0], "normal").tolist() == [0.0, 0.0, 0.0]
    assert unit_or_zero([0.0, 0.0, 1.0], "normal").tolist() == [0.0, 0.0, 1.0]
    with pytest.raises(InputError, match=r"^normal: norm 0.5, neither 0 nor 1 \(\+-0.01\)"):
        unit_or_zero([0.0, 0.0, 0.5], "normal")
    rows = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    assert unit_or_zero_rows(rows, "normals").tobytes() == rows.tobytes()
    with pytest.raises(InputError, match=r"^normals: row 1 has norm 0.5, neither 0 nor 1"):
        unit_or_zero_rows([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0]], "normals")


def test_a_point_beyond_reach_or_not_finite_is_refused() -> None:
    centre = np.zeros(3)
    near = np.array([[0.1, 0.0, 0.0], [0.0, 0.5, 0.0]])
    assert within_reach(near, centre, 0.5, "positions_m", "finger") is near
    with pytest.raises(InputError, match=r"^positions_m: entry 1 lies 0.9 m from the finger at \[0.0, 0.0, 0.0\]"):
        within_reach(np.array([[0.1, 0.0, 0.0], [0.9, 0.0, 0.0]]), centre, 0.5, "positions_m", "finger")
    with pytest.raises(InputError, match=r"^positions_m: entry 0 lies nan m from the finger"):
        within_reach(np.array([[np.nan, 0.0, 0.0]]), centre, 0.5, "positions_m", "finger")


def test_an_accumulated_reading_grows_at_most_at_its_rate_and_its_total_never_falls() -> None:
    """An outside audit: a touch's path of 1000 m 10 ms into a run ended it as "travel budget", and a path
    going back to 0 was recorded as such. A review: a restarted controller counts from 0 again (its
    touches were then all refused), and two touches handled in one real-time batch share the node's time
    (the second was refused): each reading is judged by its own stamp."""
    odometer = Accumulated("travelled_m", "m", 1e6, 1000.0)

    def read(value: float, stamp_ns: int) -> float:  # as the evaluator does with a touch it takes
        judged = odometer.judge(value, stamp_ns)
        odometer.take(judged)
        return judged.total

    assert read(0.5, 10_000_000) == 0.5  # 0.5 m in 10 ms: within 1000 m/s
    with pytest.raises(InputError, match=r"^travelled_m: grew by 1000 m in 0.01 s of its stamps, faster than 1000"):
        read(1000.5, 20_000_000)
    with pytest.raises(InputError, match=r"^travelled_m: value 1e\+308 m is outside \[0, 1e\+06\] m"):
        read(1e308, 10**15)
    assert read(0.5, 10_000_000) == 0.5  # the same reading again (a touch without travel)
    assert read(2.5, 1_010_000_000) == 2.5  # refused readings left the last one in place
    assert read(0.25, 2_000_000_000) == 2.75  # the sender restarted: a new segment, the total goes on
    assert read(1.25, 3_000_000_000) == 3.75
    assert read(0.0, 3_500_000_000) == 3.75  # restarted again
    with pytest.raises(InputError, match=r"grew by 2000 m in 1 s"):  # and judged by its rate, too
        read(2000.0, 4_500_000_000)
    # an outside walkthrough: a real-time clock source that restarted (stamps from 0) was blamed as "in 0 s"
    with pytest.raises(InputError, match=r"grew by 0.5 m in 0 s of its stamps, .* \(its stamp is 3.49 s before"):
        read(0.5, 10_000_000)
