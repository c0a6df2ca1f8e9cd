"""The fits' linear algebra, with its failures contained: solves and inverses that retry where numpy gives up, and
say in words (:class:`daq.errors.NumericalFailure`) where they cannot.

Why: the normal equations of a fit are positive semi-definite, and singular where the data do not fix a parameter or
a window's start values (a strength held at neutral, a window that never slips); numpy's LAPACK calls then raise
``LinAlgError`` ("Singular matrix", "SVD did not converge"), and a non-finite entry (a simulation that overflowed,
reaching the Jacobian) makes every later step NaN. Each function here checks its input is finite, solves as
numpy does, and where that fails, once more with a ridge of RIDGE times the diagonal's scale, then by the
pseudo-inverse (the minimum-norm solution: a direction the data do not fix is not moved). Only when that fails
too, or the input is not finite, it raises NumericalFailure naming ``what`` was being solved; a fit ends there as a
failed fit with that reason (decision 50).
"""

from __future__ import annotations

import numpy as np

from daq.errors import NumericalFailure

RIDGE = 1e-10  # relative to the mean of each matrix's diagonal: the retry's regularisation


def _finite(what: str, *arrays: np.ndarray) -> None:
    for a in arrays:
        if not np.all(np.isfinite(a)):
            raise NumericalFailure(f"{what}: the normal equations are not finite (a simulation overflowed or "
                                   f"returned NaN where a derivative was taken)")


def _ridged(A: np.ndarray) -> np.ndarray:
    """A (or each matrix of a stack) with RIDGE times the mean of its diagonal (at least 1e-300) added."""
    n = A.shape[-1]
    scale = np.abs(np.einsum("...ii->...i", A)).mean(axis=-1) if n else np.zeros(A.shape[:-2])
    return A + (RIDGE * np.maximum(scale, 1e-300))[..., None, None] * np.eye(n)


def solve(A: np.ndarray, b: np.ndarray, what: str) -> np.ndarray:
    """x with A x = b (A a matrix or a stack of them, b with matching leading axes), as np.linalg.solve; where A is
    singular: with a ridge, then the pseudo-inverse. Non-finite input, or all three failing: NumericalFailure."""
    _finite(what, A, b)
    try:
        return np.linalg.solve(A, b)
    except np.linalg.LinAlgError:
        pass
    try:
        return np.linalg.solve(_ridged(A), b)
    except np.linalg.LinAlgError:
        pass
    try:
        P = np.linalg.pinv(A)
    except np.linalg.LinAlgError as exc:
        raise NumericalFailure(f"{what}: {exc}") from None
    return P @ b if b.ndim == A.ndim else np.einsum("...ij,...j->...i", P, b)


def inverse(A: np.ndarray, what: str, ridge: bool = True) -> np.ndarray:
    """The inverse of A (or of each matrix of a stack), as np.linalg.inv; where singular: with a ridge (unless
    ``ridge`` is False), then the pseudo-inverse. Non-finite input, or every way failing: NumericalFailure."""
    _finite(what, A)
    try:
        return np.linalg.inv(A)
    except np.linalg.LinAlgError:
        pass
    if ridge:
        try:
            return np.linalg.inv(_ridged(A))
        except np.linalg.LinAlgError:
            pass
    try:
        return np.linalg.pinv(A)
    except np.linalg.LinAlgError as exc:
        raise NumericalFailure(f"{what}: {exc}") from None


def lstsq(A: np.ndarray, b: np.ndarray, what: str, rcond: float = 1e-12) -> np.ndarray:
    """The least-squares solution of A x = b (np.linalg.lstsq's first value); where the SVD does not converge, once
    more with a ridge. Non-finite input, or both failing: NumericalFailure."""
    _finite(what, A, b)
    try:
        return np.linalg.lstsq(A, b, rcond=rcond)[0]
    except np.linalg.LinAlgError:
        pass
    try:
        return np.linalg.lstsq(_ridged(A), b, rcond=rcond)[0]
    except np.linalg.LinAlgError as exc:
        raise NumericalFailure(f"{what}: {exc}") from None


# What a fit can raise on good input: our own failure, and numpy's, scipy's and Python's numerical errors that reach
# past the guards above (a NaN into scipy: ValueError; math.exp of a large argument: OverflowError). A caller that
# fits many models (a diagnosis's candidates, a proposal's rivals, the archive's records) catches these around each
# fit and reports it as failed (failure_reason); anything else is a bug and is not caught.
FAILURES = (NumericalFailure, np.linalg.LinAlgError, FloatingPointError, ZeroDivisionError, OverflowError, ValueError)


def failure_reason(exc: BaseException) -> str:
    """One line saying why a fit failed: our message as it is, numpy's with its type."""
    text = " ".join(str(exc).split()) or "(no message)"
    return text if isinstance(exc, NumericalFailure) else f"{type(exc).__name__}: {text}"
