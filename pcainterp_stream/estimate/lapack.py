"""The solve's few LAPACK/BLAS routines, called through scipy's Cython interfaces.

The estimator factorises with ``dpotrf``, inverts the factor (``dtrtri`` on small blocks,
``dtrmm`` between them) and multiplies by it with ``?trmm``: routines numpy does not
expose. ``scipy.linalg.lapack`` and ``scipy.linalg.blas`` wrap them for Python, converting
and copying their arguments while holding the GIL; sampled with ``py-spy --gil``, a
``densify`` job's densify thread held the GIL at those calls for ~0.6 s of its ~3 s (the
reading thread, the log writer and the encoders wait for it). Here the same routines are
reached through the function pointers scipy publishes for Cython
(``scipy.linalg.cython_lapack`` and ``cython_blas``) and called with :mod:`ctypes`, which
releases the GIL around each call: the job's CPU fell ~4 % and its wall time ~5 %
(docs/speed_levers.md). They are the very functions the Python wrappers call, in the same
library, so the results are the same to the bit (``tests/estimate/test_lapack.py``), but
for the triangular inverse: OpenBLAS's ``dtrtri`` took ~2.2 ms at k = 350 where the
factorisation took ~0.9, so the factor is inverted block by block
(:meth:`Routines._invert_lower`, ~0.5 ms), which differs from ``dtrtri`` in the last bits.
"""

from __future__ import annotations

import ctypes
import functools
from typing import Any, TypeVar

import numpy as np
import numpy.typing as npt

from pcainterp_stream import compiled

_Float = TypeVar("_Float", np.float32, np.float64)

_P = ctypes.c_void_p

INVERT_BLOCK = 64
"""Triangles up to this size are inverted by ``dtrtri`` itself, larger ones in halves."""


def _pointer(capsules: dict[str, Any], name: str, arguments: int) -> Any:
    """Return a ctypes function for the Cython-exported routine ``name`` (all by pointer)."""
    capsule = capsules[name]
    get_name = ctypes.pythonapi.PyCapsule_GetName
    get_name.restype = ctypes.c_char_p
    get_name.argtypes = [ctypes.py_object]
    get_pointer = ctypes.pythonapi.PyCapsule_GetPointer
    get_pointer.restype = ctypes.c_void_p
    get_pointer.argtypes = [ctypes.py_object, ctypes.c_char_p]
    address = get_pointer(capsule, get_name(capsule))
    return ctypes.CFUNCTYPE(None, *([_P] * arguments))(address)


class Routines:
    """``dpotrf``, ``dtrtri``, ``dlaset``, ``?trmm`` and ``?gemm``, called with the GIL released."""

    def __init__(self, lapack: dict[str, Any], blas: dict[str, Any]) -> None:
        self._dpotrf = _pointer(lapack, "dpotrf", 5)
        self._dtrtri = _pointer(lapack, "dtrtri", 6)
        self._dlaset = _pointer(lapack, "dlaset", 7)
        self._dtrmm = _pointer(blas, "dtrmm", 11)
        self._strmm = _pointer(blas, "strmm", 11)
        self._sgemm = _pointer(blas, "sgemm", 13)
        self._dgemm = _pointer(blas, "dgemm", 13)

    def cholesky_inverse(
        self,
        system: npt.NDArray[np.float64],
        diagonal: npt.NDArray[np.float64] | float | None = None,
    ) -> tuple[npt.NDArray[np.float64], int]:
        """Return (L^-1, info) for L L^T = ``system`` (+ ``diagonal`` on its diagonal).

        L^-1 is lower triangular, Fortran-ordered, 0 above. ``info`` is ``dpotrf``'s (> 0:
        not positive definite; L^-1 is then meaningless). The factor is scipy's
        ``dpotrf(system, lower=1)`` to the bit; its inverse matches ``dtrtri``'s to rounding
        (:meth:`_invert_lower`). ``system`` is not modified.
        """
        # symmetric: the C-ordered system read in Fortran order is the same matrix
        work = np.array(system, dtype=np.float64, order="F", copy=True)
        size = work.shape[0]
        if size == 0:
            return work, 0
        if diagonal is not None:
            work.flat[:: size + 1] += diagonal
        n = ctypes.c_int(size)
        info = ctypes.c_int(0)
        data = _P(work.ctypes.data)
        self._dpotrf(b"L", ctypes.byref(n), data, ctypes.byref(n), ctypes.byref(info))
        if info.value != 0:
            return work, int(info.value)
        # the inverse reads and writes the lower triangle only; the system's upper half is
        # still above it, cleared afterwards as scipy's clean=1 clears it after dpotrf
        self._invert_lower(work, 0, size)
        if size > 1:
            # dlaset "U" on the block from column 1: its diagonal and above are exactly the
            # strict upper triangle of the whole matrix
            zero = ctypes.c_double(0.0)
            block = ctypes.c_int(size - 1)
            self._dlaset(
                b"U",
                ctypes.byref(block),
                ctypes.byref(block),
                ctypes.byref(zero),
                ctypes.byref(zero),
                _P(work.ctypes.data + size * work.itemsize),
                ctypes.byref(n),
            )
        return work, int(info.value)

    def _invert_lower(self, work: npt.NDArray[np.float64], start: int, size: int) -> None:
        """Invert the lower triangle of the diagonal block [start:start+size] of ``work``.

        ``work`` is Fortran-ordered and square. With the block split as [[A, 0], [B, C]],
        its inverse is [[A^-1, 0], [-C^-1 B A^-1, C^-1]]: both halves inverted first (in
        place, recursively), then B multiplied by them with two ``dtrmm``. OpenBLAS's
        ``dtrtri`` spends ~2.5x its flop count's worth of ``dpotrf``'s time at k ~ 350;
        this route spends ~1.1x (matrix products only, no triangular solve).
        """
        lead = ctypes.c_int(work.shape[0])
        item = work.itemsize
        corner = work.ctypes.data + (start + start * work.shape[0]) * item
        if size <= INVERT_BLOCK:
            n = ctypes.c_int(size)
            info = ctypes.c_int(0)
            self._dtrtri(
                b"L", b"N", ctypes.byref(n), _P(corner), ctypes.byref(lead), ctypes.byref(info)
            )
            return
        first = size // 2
        self._invert_lower(work, start, first)
        self._invert_lower(work, start + first, size - first)
        top = _P(corner)
        below = _P(corner + first * item)
        bottom = _P(corner + (first + first * work.shape[0]) * item)
        rows = ctypes.c_int(size - first)
        columns = ctypes.c_int(first)
        minus_one = ctypes.c_double(-1.0)
        one = ctypes.c_double(1.0)
        # B := -C^-1 B, then B := B A^-1
        self._dtrmm(
            b"L",
            b"L",
            b"N",
            b"N",
            ctypes.byref(rows),
            ctypes.byref(columns),
            ctypes.byref(minus_one),
            bottom,
            ctypes.byref(lead),
            below,
            ctypes.byref(lead),
        )
        self._dtrmm(
            b"R",
            b"L",
            b"N",
            b"N",
            ctypes.byref(rows),
            ctypes.byref(columns),
            ctypes.byref(one),
            top,
            ctypes.byref(lead),
            below,
            ctypes.byref(lead),
        )

    def lower_times(
        self, lower: npt.NDArray[_Float], matrix: npt.NDArray[_Float], *, overwrite: bool = False
    ) -> npt.NDArray[_Float]:
        """Return ``lower @ matrix`` (C-ordered) for a lower-triangular ``lower`` (``?trmm``).

        BLAS is column-major: the C-ordered ``matrix`` is its transpose there, so the call
        computes matrix^T lower^T (right side, transposed triangle) in a copy of it, as
        ``scipy.linalg.blas``'s ``trmm(1, lower, matrix.T, lower=1, side=1, trans_a=1)``;
        with ``overwrite``, in ``matrix`` itself when it is C-ordered of the right type.
        """
        single = matrix.dtype == np.float32
        dtype = np.float32 if single else np.float64
        triangle = np.asarray(lower, dtype=dtype, order="F")
        # the product's transpose, column-major: a C-ordered copy of matrix is exactly that
        product: npt.NDArray[_Float] = (
            matrix
            if overwrite and matrix.flags.c_contiguous and matrix.dtype == dtype
            else np.array(matrix, dtype=dtype, order="C", copy=True)
        )
        rows, inner = product.shape
        if rows == 0 or inner == 0:
            return product
        m = ctypes.c_int(inner)  # rows of matrix^T
        n = ctypes.c_int(rows)  # its columns
        lda = ctypes.c_int(triangle.shape[0])
        alpha: ctypes.c_float | ctypes.c_double = (
            ctypes.c_float(1.0) if single else ctypes.c_double(1.0)
        )
        function = self._strmm if single else self._dtrmm
        function(
            b"R",
            b"L",
            b"T",
            b"N",
            ctypes.byref(m),
            ctypes.byref(n),
            ctypes.byref(alpha),
            _P(triangle.ctypes.data),
            ctypes.byref(lda),
            _P(product.ctypes.data),
            ctypes.byref(m),
        )
        return product

    def add_product(
        self, total: npt.NDArray[_Float], left: npt.NDArray[_Float], right: npt.NDArray[_Float]
    ) -> None:
        """``total += left @ right`` in place (``?gemm`` with beta 1: no temporary product).

        All three C-ordered of one type: column-major, that is total^T += right^T left^T.
        """
        single = total.dtype == np.float32
        dtype = np.float32 if single else np.float64
        if not (total.flags.c_contiguous and total.dtype == dtype):
            raise ValueError("add_product needs a C-ordered float32 or float64 total")
        rows, columns = total.shape
        inner = left.shape[1]
        if left.shape != (rows, inner) or right.shape != (inner, columns):
            raise ValueError(f"shapes {left.shape} @ {right.shape} do not give {total.shape}")
        if rows == 0 or columns == 0 or inner == 0:
            return
        first = np.ascontiguousarray(right, dtype=dtype)
        second = np.ascontiguousarray(left, dtype=dtype)
        m, n, k = ctypes.c_int(columns), ctypes.c_int(rows), ctypes.c_int(inner)
        one: ctypes.c_float | ctypes.c_double = (
            ctypes.c_float(1.0) if single else ctypes.c_double(1.0)
        )
        (self._sgemm if single else self._dgemm)(
            b"N",
            b"N",
            ctypes.byref(m),
            ctypes.byref(n),
            ctypes.byref(k),
            ctypes.byref(one),
            _P(first.ctypes.data),
            ctypes.byref(m),
            _P(second.ctypes.data),
            ctypes.byref(k),
            ctypes.byref(one),
            _P(total.ctypes.data),
            ctypes.byref(m),
        )


@functools.cache
def routines() -> Routines | None:
    """Return the routines of scipy's LAPACK and BLAS; None when they cannot be reached.

    Loads scipy's Cython interfaces to them (:func:`pcainterp_stream.compiled.module`,
    without the rest of ``scipy.linalg``), its OpenBLAS held at one thread. None for a
    scipy whose interfaces lack one of them or a Python without ``ctypes.pythonapi``: the
    callers then use ``scipy.linalg.lapack`` and ``scipy.linalg.blas`` as they are.
    """
    try:
        found = Routines(
            compiled.module("linalg.cython_lapack").__pyx_capi__,
            compiled.module("linalg.cython_blas").__pyx_capi__,
        )
    except (ImportError, AttributeError, KeyError, ValueError):  # pragma: no cover
        return None
    compiled.hold_scipy_blas_at_one_thread()
    return found
