"""numerics.skew, the cross-product matrices of N vectors: against NumPy's cross product."""

from __future__ import annotations

import numpy as np

from qpik.numerics import skew


def test_skew_times_columns_is_the_cross_product_of_each_world():
    rng = np.random.default_rng(0)
    for n in (1, 5):
        vectors, columns = rng.normal(size=(n, 3)), rng.normal(size=(n, 3, 7))
        matrices = skew(vectors, np.zeros((n, 3, 3)))
        expected = np.cross(vectors[:, :, None], columns, axis=1)
        # Two products and a difference per entry in either: rounding of O(1) values.
        np.testing.assert_allclose(matrices @ columns, expected, rtol=0, atol=1e-15)
        np.testing.assert_array_equal(matrices, -matrices.transpose(0, 2, 1))
        np.testing.assert_array_equal(np.einsum("nii->ni", matrices), 0.0)
