r"""Linear recursions (IIR filters) along the last axis, run by LAPACK's banded triangular solve.

The recursion

.. math:: \sum_{i=0}^{k} a_i\, y_{n-i} = \sum_{j=0}^{q} b_j\, x_{n-j} + z_n,
          \qquad y_{-1} = \dots = y_{-k} = 0,\ x_{-1} = \dots = 0,

for n = 0 … N − 1 (z_n a given initial-condition input, zero for n ≥ its length) is what
``scipy.signal.lfilter(b, a, x, zi=z)`` computes: lfilter's direct-form-II-transposed state
``zi`` enters the output exactly as the extra input z_n on the first samples. Written for all n
at once, the left side is T y with T the N × N lower-triangular banded Toeplitz matrix
T_{n, n−i} = a_i, so y = T⁻¹ v with v_n = Σ_j b_j x_{n−j} + z_n, and forward substitution on T
*is* the recursion, sample after sample. :func:`recurse` forms v by a shift-sum (the numerator is
short) and solves T y = v by LAPACK's ``dtbtrs``, which runs the substitution in compiled code
for many right-hand sides at once. It is given T's transpose (upper banded storage,
``trans = 'T'``), so each y_n is one dot product of the k previous outputs with the
coefficients; with a₀ = 1 the diagonal is a unit one (``diag = 'U'``), never divided by.

Rows that have their own denominator (``a`` of shape (R, k + 1)) are laid end to end into one
long sequence whose banded matrix holds each row's coefficients in that row's columns, with
zeros where a coefficient would reach back into the previous row: one solve for many rows.

The arithmetic is that of the recursion itself (k multiply–adds per sample, in another order
than lfilter's), so the results agree with lfilter's to rounding; a growing (unstable)
recursion grows, and overflows to ±inf or nan, as lfilter's does.
"""

from __future__ import annotations

import threading

import numpy as np
from numpy.typing import ArrayLike
from scipy.linalg.lapack import dtbtrs

__all__ = ["recurse"]

# per-row denominators: rows are solved together in chunks whose banded matrix has at most this
# many entries (8 MiB), so memory stays bounded for long records and large batches
_CHUNK_ENTRIES = 1 << 20
_scratch = threading.local()  # per-thread memory for the bands (see _band)


def recurse(
    a: ArrayLike,
    x: ArrayLike,
    b: ArrayLike | None = None,
    zi: ArrayLike | None = None,
    overwrite_x: bool = False,
) -> np.ndarray:
    r"""Run Σᵢ aᵢ y_{n−i} = Σⱼ bⱼ x_{n−j} + z_n along the last axis of ``x`` (``lfilter``'s result).

    Parameters
    ----------
    a : array_like, shape (k + 1,) or (R, k + 1)
        Denominator coefficients a₀ … a_k, a₀ ≠ 0 (the recursion is normalised by a₀, as
        ``lfilter`` does). One row shared by every sequence of ``x``, or one row per sequence
        (R = ``x[..., 0].size``, in C order).
    x : array_like, shape (..., N)
        Input sequences along the last axis.
    b : array_like, shape (q + 1,), optional
        Numerator (FIR) coefficients, shared; default ``[1.0]``.
    zi : array_like, shape (..., K), optional
        Initial conditions in ``lfilter``'s sense (its direct-form-II-transposed state, K ≤ N,
        broadcasting against ``x[..., :K]``); they add z_n to the first K inputs of the recursion.
    overwrite_x : bool, optional
        Allow the result to be written into ``x`` (a C-contiguous float64 array, no ``b``) when
        the caller no longer needs it; saves a copy. Default False.

    Returns
    -------
    numpy.ndarray, shape of ``x``
        The outputs y (float64). Unlike ``lfilter`` with ``zi``, the final state is not returned.

    Notes
    -----
    Forward substitution on the unit-lower-triangular banded Toeplitz system T y = v,
    T_{n, n−i} = a_i / a₀, v = (b ∗ x + z)/a₀, is the recursion; ``dtbtrs`` runs it (see the
    module docstring). Entries a_i with i ≥ N never act and are dropped.

    Examples
    --------
    >>> import numpy as np
    >>> recurse([1.0, -0.5], np.array([1.0, 0.0, 0.0, 0.0]))
    array([1.   , 0.5  , 0.25 , 0.125])
    >>> recurse([1.0, -1.0], np.ones(4), b=[2.0], zi=[10.0])
    array([12., 14., 16., 18.])
    """
    x = np.asarray(x, dtype=float)
    a = np.asarray(a, dtype=float)
    n = x.shape[-1]
    if b is None:  # the solve overwrites v
        v = x if overwrite_x and x.flags.c_contiguous else np.array(x, dtype=float, order="C")
    else:
        b = np.asarray(b, dtype=float).ravel()
        v = np.multiply(x, b[0], order="C")
        for j in range(1, min(b.size, n)):  # shift-sum over the (few) numerator taps
            v[..., j:] += b[j] * x[..., :-j]
    if zi is not None:
        zi = np.asarray(zi, dtype=float)
        v[..., : zi.shape[-1]] += zi
    if v.size == 0:
        return v
    rows = v.reshape(-1, n)
    if a.ndim == 1:
        a = a[:n]  # coefficients beyond the record never act
        if a[0] != 1.0:
            rows /= a[0]
            a = a / a[0]
        return _solve_shared(a, rows).reshape(v.shape)
    if a.shape[0] != rows.shape[0]:
        raise ValueError(
            f"`a` must have one row per sequence ({rows.shape[0]}); got shape {a.shape}"
        )
    a = a[:, :n]
    if np.any(a[:, 0] != 1.0):
        rows /= a[:, :1]
        a = a / a[:, :1]
    return _solve_rows(a, rows).reshape(v.shape)


def _solve_shared(a: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Solve every row (R, N) with the one recursion a (k + 1,), a₀ = 1; in place."""
    if a.size == 1:
        return rows
    n, k = rows.shape[1], a.size - 1
    ab = _band(k + 1, n)  # upper band of Tᵀ: row k − i holds a_i
    key = (n, a.tobytes())
    fresh = (k + 1) * n > _CHUNK_ENTRIES  # not from the scratch memory
    if fresh or getattr(_scratch, "key", None) != key:  # not the band the last call left
        for i in range(k + 1):
            ab[k - i] = a[i]
        if not fresh:
            _scratch.key = key
    y, info = dtbtrs(ab, rows.T, "U", "T", "U", 1)  # uplo, trans, diag, overwrite_b
    if info != 0:  # only argument errors are possible with a unit diagonal
        raise RuntimeError(f"dtbtrs failed (info = {info})")
    return y.T


def _band(k1: int, n: int) -> np.ndarray:
    """An uninitialised (k1, n) Fortran-order array for a band, from this thread's scratch.

    A simulation runs one recursion after another; reusing the memory spares the page faults
    of a fresh band on every call (a band up to ``_CHUNK_ENTRIES`` entries; larger ones are
    allocated).
    """
    size = k1 * n
    if size > _CHUNK_ENTRIES:
        return np.empty((k1, n), order="F")
    buf = getattr(_scratch, "buf", None)
    if buf is None or buf.size < size:
        buf = _scratch.buf = np.empty(max(size, 4096))
        _scratch.key = None
    return buf[:size].reshape(n, k1).T


def _solve_rows(a: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Solve row r of ``rows`` (R, N) with the recursion a[r] (R, k + 1), a[:, 0] = 1; in place.

    Rows are laid end to end (a chunk at a time) and solved as one sequence whose banded matrix
    carries each row's coefficients in that row's columns and zeros across row boundaries.
    """
    R, n = rows.shape
    k = a.shape[1] - 1
    if k == 0:
        return rows
    per = max(1, _CHUNK_ENTRIES // ((k + 1) * n))
    for r0 in range(0, R, per):
        r1 = min(R, r0 + per)
        ab = _band(k + 1, (r1 - r0) * n)
        _scratch.key = None  # the shared band, if any, is overwritten
        abt = ab.T.reshape(r1 - r0, n, k + 1)  # a view: row r's columns, transposed
        abt[...] = a[r0:r1, None, ::-1]
        for i in range(1, k + 1):  # a_i would reach into the previous row
            abt[:, : min(i, n), k - i] = 0.0
        y, info = dtbtrs(ab, rows[r0:r1].reshape(-1, 1), "U", "T", "U", 1)
        if info != 0:
            raise RuntimeError(f"dtbtrs failed (info = {info})")
        rows[r0:r1] = y.reshape(r1 - r0, n)
    return rows
