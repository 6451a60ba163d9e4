"""Complex-step derivatives: exact to rounding error for analytic functions written with complex-safe
numpy operations (all plant and controller functions here are)."""
from __future__ import annotations

from typing import Callable

import numpy as np


def _steps(x: np.ndarray, scale: np.ndarray | None) -> np.ndarray:
    ref = np.abs(x) if scale is None else np.asarray(scale, dtype=float)
    return 1e-20 * np.where(ref > 0, ref, 1.0)


def gradient(f: Callable[[np.ndarray], complex], x: np.ndarray, scale: np.ndarray | None = None) -> np.ndarray:
    """grad f(x) of a scalar function by the complex step, h_k = 1e-20 * scale_k."""
    x = np.asarray(x, dtype=float)
    h = _steps(x, scale)
    g = np.empty(x.size)
    for k in range(x.size):
        xc = x.astype(complex)
        xc[k] += 1j * h[k]
        g[k] = np.imag(f(xc)) / h[k]
    return g


def jacobian(f: Callable[[np.ndarray], np.ndarray], x: np.ndarray, scale: np.ndarray | None = None) -> np.ndarray:
    """df/dx of a vector function by the complex step (columns k = df/dx_k)."""
    x = np.asarray(x, dtype=float)
    h = _steps(x, scale)
    cols = []
    for k in range(x.size):
        xc = x.astype(complex)
        xc[k] += 1j * h[k]
        cols.append(np.imag(np.atleast_1d(f(xc))) / h[k])
    return np.stack(cols, axis=1)
