"""Argument checks of the GP functions: shapes, finiteness and hyperparameter signs.

Each raises ``ValueError`` naming the argument and what was expected.
"""

from __future__ import annotations

import math

import numpy as np


def _is_int(value) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def _as_finite_array(name: str, value, ndim: int) -> np.ndarray:
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a numeric array; got {type(value).__name__}") from exc
    if array.ndim != ndim:
        raise ValueError(f"{name} must be {ndim}-D; got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must contain only finite values (no NaN/inf)")
    return array


def _check_matrix(name: str, value, n_rows: int | None = None, n_cols: int | None = None) -> np.ndarray:
    array = _as_finite_array(name, value, 2)
    expected = f"({n_rows if n_rows is not None else 'n'}, {n_cols if n_cols is not None else 'd'})"
    if (n_rows is not None and array.shape[0] != n_rows) or (n_cols is not None and array.shape[1] != n_cols):
        raise ValueError(f"{name} must have shape {expected}; got {array.shape}")
    if array.shape[0] == 0 or array.shape[1] == 0:
        raise ValueError(f"{name} must be non-empty with shape {expected}; got {array.shape}")
    return array


def _check_vector(name: str, value, length: int) -> np.ndarray:
    array = _as_finite_array(name, value, 1)
    if array.shape != (length,):
        raise ValueError(f"{name} must have shape ({length},); got {array.shape}")
    return array


def _check_theta(name: str, value, n_inputs: int) -> np.ndarray:
    """theta = [sf2, sn2, l_1..l_d], finite and > 0 (sn2 may be 0)."""
    try:
        theta = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a numeric array [sf2, sn2, l_1..l_d]") from exc
    if theta.shape != (n_inputs + 2,):
        raise ValueError(
            f"{name} must have shape (d+2,) = ({n_inputs + 2},) as [sf2, sn2, l_1..l_{n_inputs}]; "
            f"got shape {theta.shape}"
        )
    _check_theta_values(name, theta)
    return theta


def _check_theta_values(name: str, theta: np.ndarray) -> None:
    if not np.all(np.isfinite(theta)):
        raise ValueError(f"{name} must be finite")
    if theta[..., 0].min() <= 0.0:
        raise ValueError(f"{name}: sf2 (index 0) must be > 0")
    if theta[..., 1].min() < 0.0:
        raise ValueError(f"{name}: sn2 (index 1) must be >= 0")
    if theta[..., 2:].min() <= 0.0:
        raise ValueError(f"{name}: lengthscales (index 2..) must be > 0")


def _check_thetas(thetas, n_outputs: int, n_inputs: int) -> np.ndarray:
    """thetas (n_outputs, d+2): one row [sf2, sn2, l_1..l_d] per output, as `_check_theta`."""
    thetas = _as_finite_array("thetas", thetas, 2)
    if thetas.shape != (n_outputs, n_inputs + 2):
        raise ValueError(
            f"thetas must have shape (n_outputs, d+2) = ({n_outputs}, {n_inputs + 2}), one row "
            f"[sf2, sn2, l_1..l_d] per output; got {thetas.shape}"
        )
    _check_theta_values("thetas", thetas)
    return thetas


def _check_jitter(jitter) -> float:
    if not (isinstance(jitter, (int, float)) and math.isfinite(jitter) and jitter >= 0.0):
        raise ValueError(f"jitter must be a finite float >= 0; got {jitter!r}")
    return float(jitter)
