"""``unique_rows`` is ``np.unique(axis=0)`` with inverse and counts, identically and in order."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from artitwin_core.geometry import unique_rows


def _reference(keys):
    rows, inv, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    return rows, inv.reshape(-1), counts


@settings(max_examples=60, deadline=None)
@given(arrays(np.int64, st.tuples(st.integers(0, 300), st.integers(1, 4)), elements=st.integers(-50, 50)))
def test_same_rows_inverse_and_counts_as_numpy(keys):
    got, ref = unique_rows(keys), _reference(keys)
    for g, r in zip(got, ref, strict=True):
        np.testing.assert_array_equal(g, r)


def test_voxel_keys_of_a_cloud_and_the_overflow_fallback():
    rng = np.random.default_rng(0)
    keys = np.floor(rng.normal(size=(20000, 3)) / 0.005).astype(np.int64)
    for g, r in zip(unique_rows(keys), _reference(keys), strict=True):
        np.testing.assert_array_equal(g, r)
    wide = np.array([[0, 0], [2**40, -(2**40)], [0, 0], [-(2**40), 5]], np.int64)  # packing would overflow
    for g, r in zip(unique_rows(wide), _reference(wide), strict=True):
        np.testing.assert_array_equal(g, r)


def test_rejects_float_keys():
    with pytest.raises(ValueError, match="integer keys"):
        unique_rows(np.zeros((3, 3)))
