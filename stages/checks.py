"""Invariant checks shared by every stage's dataclasses.

Each check raises `ContractError` naming the dataclass field, what was found and what was
expected, so a broken stage output fails at construction, not three stages later.
"""
from __future__ import annotations

import numpy as np


class ContractError(ValueError):
    """A stage's output dataclass was built with data that breaks its documented invariants."""


def check_array(owner: str, name: str, a, shape: tuple, dtype, *, finite: bool = True) -> np.ndarray:
    """Check `a` is an ndarray of `dtype` kind with `shape` (None = any size for that axis).

    Returns the array (never copies) so `__post_init__` can use the result directly.
    """
    where = f"{owner}.{name}"
    if not isinstance(a, np.ndarray):
        raise ContractError(f"{where}: expected a numpy array, got {type(a).__name__}")
    if a.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, a.shape)):
        want = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
        raise ContractError(f"{where}: expected shape {want}, got {a.shape}")
    if np.dtype(dtype) != a.dtype:
        raise ContractError(f"{where}: expected dtype {np.dtype(dtype)}, got {a.dtype}")
    if finite and a.dtype.kind == "f" and a.size and not np.isfinite(a).all():
        bad = np.argwhere(~np.isfinite(a))[0]
        raise ContractError(f"{where}: non-finite value at index {tuple(int(i) for i in bad)}")
    return a


def check_index(owner: str, name: str, a: np.ndarray, upper: int, *, allow: int | None = None) -> None:
    """Check integer array `a` holds indices in [0, upper) (or the sentinel `allow`, e.g. -1)."""
    if a.size == 0:
        return
    ok = (a >= 0) & (a < upper)
    if allow is not None:
        ok |= a == allow
    if not ok.all():
        i = int(np.argmax(~ok.ravel()))
        raise ContractError(
            f"{owner}.{name}: index {int(a.ravel()[i])} out of range [0, {upper}) at flat position {i}"
        )


def check_rigid(owner: str, name: str, m: np.ndarray, tol: float = 1e-6) -> None:
    """Check a (..., 4, 4) stack holds rigid transforms (orthonormal rotation, last row 0 0 0 1)."""
    r = m[..., :3, :3]
    eye = np.einsum("...ij,...kj->...ik", r, r)
    if not np.allclose(eye, np.eye(3), atol=tol) or not np.allclose(m[..., 3, :], [0, 0, 0, 1], atol=tol):
        raise ContractError(f"{owner}.{name}: expected rigid 4x4 transforms (rotation + translation)")


def check_positive(owner: str, name: str, value: float, *, strict: bool = True) -> None:
    if not np.isfinite(value) or (value <= 0 if strict else value < 0):
        raise ContractError(f"{owner}.{name}: expected a {'positive' if strict else 'non-negative'} number, got {value}")
