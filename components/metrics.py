"""Performance measures of a closed-loop run, computed from samples (used by tests and reports).

All take the time grid t and the position error e(t) = q(t) - q*(t) (first mechanical coordinate).
"""
from __future__ import annotations

import numpy as np


def oscillations(e: np.ndarray, band: float) -> int:
    """Number of sign changes of e, ignoring samples with |e| <= band (a dead band against noise)."""
    s = np.sign(e[np.abs(e) > band])
    return int(np.count_nonzero(s[1:] != s[:-1]))


def overshoot(e: np.ndarray) -> float:
    """Largest excursion past zero, opposite to the initial error, relative to |e(0)|."""
    if e[0] == 0:
        return 0.0
    return float(max(0.0, np.max(-np.sign(e[0]) * e)) / abs(e[0]))


def settling_time(t: np.ndarray, e: np.ndarray, band: float) -> float:
    """First time after which |e| stays within `band`; inf if it never does."""
    outside = np.nonzero(np.abs(e) > band)[0]
    if outside.size == 0:
        return float(t[0])
    if outside[-1] == len(e) - 1:
        return float("inf")
    return float(t[outside[-1] + 1])


def ise(t: np.ndarray, e: np.ndarray) -> float:
    """Integral of the squared error (trapezoidal rule)."""
    return float(np.trapezoid(e ** 2, t))


def window_peaks(e: np.ndarray, n_windows: int) -> np.ndarray:
    """max |e| over n_windows consecutive equal windows of the samples (an error envelope); with
    fewer samples than windows, one window per sample."""
    if len(e) == 0:
        raise ValueError("window_peaks needs at least one sample")
    n_windows = min(n_windows, len(e))
    k = len(e) // n_windows
    return np.abs(e[:k * n_windows]).reshape(n_windows, k).max(axis=1)
