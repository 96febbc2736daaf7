"""Welding: equal coordinates merge in first-occurrence order; repeated faces are found exactly."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st


@pytest.mark.parametrize("collide", ["none", "some", "all"])
def test_weld_merges_equal_coordinates_in_first_occurrence_order(monkeypatch, collide):
    """Equal coordinates (and -0.0 / 0.0) become one vertex, first occurrences keep their order, a welded
    mesh is unchanged, and the exact regrouping gives the same answer when some or every hash collides."""
    from heoslice.mesh import weld

    if collide == "all":
        monkeypatch.setattr(weld, "row_hash", lambda bits: np.zeros(len(bits), dtype=np.uint64))
    elif collide == "some":  # rows with the same x collide whatever their y and z
        monkeypatch.setattr(weld, "row_hash", lambda bits: bits[:, 0].astype(np.uint64) << np.uint64(40))
    rng = np.random.default_rng(5)
    vertices = rng.integers(-2, 3, (300, 3)).astype(np.float32)
    vertices[vertices == 0] = -0.0
    faces = rng.integers(0, 300, (200, 3))
    unique, welded_faces, first = weld.weld_vertices(vertices, faces)
    np.testing.assert_array_equal(unique[welded_faces], (vertices[faces] + 0.0).astype(np.float64))
    assert len(unique) == len(np.unique(vertices + 0.0, axis=0))
    assert np.all(np.diff(first) > 0) and first[0] == 0
    np.testing.assert_array_equal(unique, vertices[first] + 0.0)
    assert np.all(first[welded_faces] <= faces)  # each vertex maps to the first occurrence of its coordinates
    again, again_faces, _ = weld.weld_vertices(unique, welded_faces)
    np.testing.assert_array_equal(again, unique)
    np.testing.assert_array_equal(again_faces, welded_faces)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(0, 400), st.sampled_from([np.float32, np.float64]))
def test_weld_is_a_first_occurrence_dictionary_of_the_coordinate_bits(seed, count, dtype):
    """weld_vertices' first occurrences and vertex map equal those of a dictionary of each row's bits
    (-0.0 taken as 0.0), for float32 and float64 rows with many repeats, none, or no rows at all."""
    from heoslice.mesh.weld import weld_vertices

    rng = np.random.default_rng(seed)
    vertices = (rng.integers(-3, 4, (count, 3)) * rng.choice([0.5, 1e-7, 3.0])).astype(dtype)
    vertices[rng.random((count, 3)) < 0.1] = -0.0
    faces = rng.integers(0, max(count, 1), (2 * count, 3)) if count else np.zeros((0, 3), np.int64)
    seen: dict[bytes, int] = {}
    first, new = [], []
    for i, row in enumerate(vertices + dtype(0.0)):
        if row.tobytes() not in seen:
            seen[row.tobytes()] = len(first)
            first.append(i)
        new.append(seen[row.tobytes()])
    unique, welded_faces, got_first = weld_vertices(vertices, faces)
    np.testing.assert_array_equal(got_first, first)
    np.testing.assert_array_equal(welded_faces, np.asarray(new, dtype=np.int64)[faces] if count else faces)
    np.testing.assert_array_equal(unique, (vertices[first] + dtype(0.0)).astype(np.float64))


@pytest.mark.parametrize("collide", ["none", "all"])
def test_duplicate_faces_are_the_repeats_of_an_earlier_face(monkeypatch, collide):
    """duplicate_faces flags exactly the faces equal (up to rotation, same orientation) to an earlier one, as a
    set-based reference says, also when every hash collides; reversed faces are not duplicates."""
    from heoslice.mesh import weld

    if collide == "all":
        monkeypatch.setattr(weld, "row_hash", lambda bits: np.zeros(len(bits), dtype=np.uint64))
    rng = np.random.default_rng(8)
    faces = np.array([rng.choice(6, 3, replace=False) for _ in range(400)])
    seen, expected = set(), []
    for face in faces.tolist():
        key = min(tuple(face[i:] + face[:i]) for i in range(3))
        expected.append(key in seen)
        seen.add(key)
    np.testing.assert_array_equal(weld.duplicate_faces(faces), expected)
    assert not weld.duplicate_faces(np.array([[0, 1, 2], [0, 2, 1]])).any()


@settings(max_examples=80, deadline=None)
@given(channels=st.integers(1, 6), rows=st.integers(0, 3000), distinct=st.integers(1, 40), seed=st.integers(0, 2**16),
       wide=st.booleans())
def test_distinct_rows_are_first_occurrences_of_each_row_by_its_bits(channels, rows, distinct, seed, wide):
    """distinct_rows gives each distinct row of float32 or float64 values once, by its bits (0.0 and -0.0 apart),
    at its first occurrence, in order, and every row's index among them: np.unique(axis=0) of the bits, and
    a walk over the rows keeping the first of each."""
    from heoslice.mesh.weld import distinct_rows

    rng = np.random.default_rng(seed)
    dtype = np.float64 if wide else np.float32
    values = rng.choice(np.array([0.0, -0.0, 1.0, 0.25, 1e-7], dtype=dtype), (distinct, channels))
    values[: distinct // 2] = rng.random((distinct // 2, channels))
    flat = values.astype(dtype)[rng.integers(0, distinct, rows)]
    row_index, first = distinct_rows(flat)
    bits = flat.view(np.uint64 if wide else np.uint32)
    seen = {}
    for i, row in enumerate(map(bytes, bits)):
        seen.setdefault(row, i)
    np.testing.assert_array_equal(first, sorted(seen.values()))
    assert len(first) == len(np.unique(bits, axis=0))
    np.testing.assert_array_equal(bits[first][row_index], bits)
