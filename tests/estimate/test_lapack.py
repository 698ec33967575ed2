"""The solve's LAPACK called with the GIL released: the same bits as scipy.linalg's wrappers."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import blas
from scipy.linalg import lapack as scipy_lapack

from pcainterp_stream.estimate import lapack, solve


@pytest.fixture(scope="module")
def routines() -> lapack.Routines:
    found = lapack.routines()
    if found is None:  # pragma: no cover - scipy's wheels publish them
        pytest.skip("this scipy has no Cython LAPACK interface (the solve uses scipy.linalg)")
    return found


def _system(rng: np.random.Generator, k: int) -> np.ndarray:
    rows = rng.standard_normal((k, 40))
    return rows @ rows.T + 0.05 * np.eye(k)


@pytest.mark.parametrize("k", [1, 2, 7, lapack.INVERT_BLOCK, 150, 363])
def test_cholesky_inverse_is_scipys_up_to_rounding(routines: lapack.Routines, k: int) -> None:
    """dpotrf's factor, inverted: dtrtri's bits up to INVERT_BLOCK, its values beyond."""
    system = _system(np.random.default_rng(k), k)
    lower, info = scipy_lapack.dpotrf(system, lower=1, clean=1)
    expected, _ = scipy_lapack.dtrtri(lower, lower=1)
    inverse, info = routines.cholesky_inverse(system)
    assert info == 0
    assert inverse.flags.f_contiguous
    np.testing.assert_array_equal(inverse, np.tril(inverse))
    if k <= lapack.INVERT_BLOCK:
        np.testing.assert_array_equal(inverse, expected)
    else:  # blocks inverted apart: another order of the same sums
        assert not np.array_equal(inverse, expected)
        scale = float(np.abs(expected).max())
        np.testing.assert_allclose(inverse, expected, rtol=0.0, atol=1e-12 * scale)
    np.testing.assert_allclose(inverse @ lower, np.eye(k), atol=1e-12)
    np.testing.assert_allclose(inverse @ system @ inverse.T, np.eye(k), atol=1e-8)
    np.testing.assert_array_equal(solve._cholesky_inverse(system), inverse)


@pytest.mark.parametrize("k", [5, 200])
def test_cholesky_inverse_adds_the_diagonal_to_a_copy(routines: lapack.Routines, k: int) -> None:
    rng = np.random.default_rng(k)
    system = _system(rng, k)
    before = system.copy()
    diagonal = rng.uniform(0.5, 2.0, k)
    added = system.copy()
    added.flat[:: k + 1] += diagonal
    inverse, info = routines.cholesky_inverse(system, diagonal)
    assert info == 0
    np.testing.assert_array_equal(system, before)
    np.testing.assert_array_equal(inverse, routines.cholesky_inverse(added)[0])
    np.testing.assert_array_equal(
        solve._cholesky_inverse(system, 3.0), solve._cholesky_inverse(system + 3.0 * np.eye(k))
    )


def test_cholesky_inverse_of_nothing(routines: lapack.Routines) -> None:
    inverse, info = routines.cholesky_inverse(np.zeros((0, 0)))
    assert info == 0
    assert inverse.shape == (0, 0)


def test_cholesky_inverse_reports_not_positive_definite(routines: lapack.Routines) -> None:
    system = -np.eye(5)
    _, info = routines.cholesky_inverse(system)
    assert info > 0
    with pytest.raises(np.linalg.LinAlgError, match="not positive definite"):
        solve._cholesky_inverse(system)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("shape", [(1, 1), (9, 3), (150, 30), (363, 4)])
def test_lower_times_is_scipys_trmm(
    routines: lapack.Routines, dtype: type, shape: tuple[int, int]
) -> None:
    rng = np.random.default_rng(shape[0])
    k = shape[0]
    lower = np.tril(rng.standard_normal((k, k)))
    lower = np.asfortranarray(lower if dtype is np.float64 else lower.astype(np.float32))
    matrix = rng.standard_normal(shape).astype(dtype)
    trmm = blas.strmm if dtype is np.float32 else blas.dtrmm
    expected = np.ascontiguousarray(
        trmm(1.0, lower, np.ascontiguousarray(matrix).T, lower=1, side=1, trans_a=1).T
    )
    product = routines.lower_times(lower, matrix)
    assert product.dtype == dtype
    assert product.flags.c_contiguous
    np.testing.assert_array_equal(product, expected)
    np.testing.assert_allclose(product, lower @ matrix, rtol=1e-4, atol=1e-4)
    np.testing.assert_array_equal(solve._lower_times(lower, matrix), expected)


def test_lower_times_of_a_float64_factor_and_float32_rows(routines: lapack.Routines) -> None:
    """The variance's call: a float64 L^-1 times float32 rows, as scipy's strmm casts it."""
    rng = np.random.default_rng(3)
    lower = np.asfortranarray(np.tril(rng.standard_normal((50, 50))))
    matrix = rng.standard_normal((50, 20)).astype(np.float32)
    expected = np.ascontiguousarray(blas.strmm(1.0, lower, matrix.T, lower=1, side=1, trans_a=1).T)
    np.testing.assert_array_equal(routines.lower_times(lower, matrix), expected)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_lower_times_may_overwrite_its_matrix(routines: lapack.Routines, dtype: type) -> None:
    rng = np.random.default_rng(11)
    lower = np.asfortranarray(np.tril(rng.standard_normal((30, 30))).astype(dtype))
    matrix = rng.standard_normal((30, 70)).astype(dtype)
    expected = routines.lower_times(lower, matrix)
    given = matrix.copy()
    product = solve._lower_times(lower, given, overwrite=True)
    assert product is given
    np.testing.assert_array_equal(product, expected)
    # a view that is not C-ordered is copied, as without overwrite
    columns = np.asfortranarray(matrix)
    np.testing.assert_array_equal(solve._lower_times(lower, columns, overwrite=True), expected)
    np.testing.assert_array_equal(columns, matrix)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("shape", [(1, 1, 1), (9, 3, 5), (363, 150, 1872), (4, 0, 6)])
def test_add_product_adds_the_gemm_in_place(
    routines: lapack.Routines, dtype: type, shape: tuple[int, int, int]
) -> None:
    rows, inner, columns = shape
    rng = np.random.default_rng(rows)
    total = rng.standard_normal((rows, columns)).astype(dtype)
    left = rng.standard_normal((rows, inner)).astype(dtype)
    right = rng.standard_normal((inner, columns)).astype(dtype)
    expected = total + left @ right
    place = total.ctypes.data
    solve._add_product(total, left, right)
    assert total.ctypes.data == place
    tolerance = 1e-4 if dtype is np.float32 else 1e-12
    np.testing.assert_allclose(total, expected, rtol=tolerance, atol=tolerance * max(inner, 1))


def test_add_product_refuses_what_it_cannot_add_to(routines: lapack.Routines) -> None:
    with pytest.raises(ValueError, match="C-ordered"):
        routines.add_product(np.zeros((3, 4), order="F"), np.zeros((3, 2)), np.zeros((2, 4)))
    with pytest.raises(ValueError, match="do not give"):
        routines.add_product(np.zeros((3, 4)), np.zeros((3, 2)), np.zeros((3, 4)))
