"""Row helpers of the integrator (renderer/kernels/rows.py) against numpy's own semantics."""

from __future__ import annotations

import numpy as np

from renderer.kernels.rows import add_rows, take_rows


def test_add_rows_accumulates_repeated_rows_like_add_at():
    rng = np.random.default_rng(3)
    idx = rng.integers(0, 50, size=400)  # many repeats
    v = rng.random((400, 3))
    L, ref = np.zeros((50, 3)), np.zeros((50, 3))
    add_rows(L, idx, v)
    np.add.at(ref, idx, v)
    np.testing.assert_allclose(L, ref, rtol=1e-13)
    # A plain fancy-index add would have dropped the repeats: the test sees the difference.
    lost = np.zeros((50, 3))
    lost[idx] += v
    assert not np.allclose(lost, ref)


def test_add_rows_broadcasts_and_handles_empty_and_non_contiguous():
    L = np.zeros((4, 3))
    add_rows(L, np.array([1, 1]), np.array([1.0, 2.0, 3.0]))
    np.testing.assert_array_equal(L[1], [2.0, 4.0, 6.0])
    add_rows(L, np.zeros(0, np.int64), np.zeros((0, 3)))
    Lt = np.zeros((3, 4)).T  # (4, 3), not C-contiguous: falls back to np.add.at
    add_rows(Lt, np.array([2, 2]), np.ones((2, 3)))
    np.testing.assert_array_equal(Lt[2], [2.0, 2.0, 2.0])


def test_take_rows_is_fancy_indexing():
    a = np.arange(30.0).reshape(10, 3)
    idx = np.array([9, 0, 0, 4])
    np.testing.assert_array_equal(take_rows(a, idx), a[idx])
