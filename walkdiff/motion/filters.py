"""Temporal smoothing of motion features: Savitzky–Golay (DiffMotion removes sampling jitter with it)."""

from __future__ import annotations

import numpy as np
from scipy.signal import savgol_filter

from walkdiff.common.errors import WalkdiffError


def savgol(x: np.ndarray, window: int = 31, order: int = 4, axis: int = 0) -> np.ndarray:
    """Savitzky–Golay filter along `axis` (frames): a local least-squares polynomial fit per frame.

    A clip shorter than `window` is filtered with the longest odd window it holds; one too short for a
    polynomial of `order` (at most `order` + 1 frames) comes back unchanged, as there is nothing to fit.
    The ends are fitted by the polynomial of the first / last window (scipy's 'interp' mode), so the
    clip keeps its length and its first and last poses are not pulled towards zero.
    """
    if window < 1 or window % 2 == 0:
        raise WalkdiffError(f"the Savitzky–Golay window must be a positive odd number, got {window}")
    if not 0 <= order < window:
        raise WalkdiffError(f"the Savitzky–Golay order must be in [0, window), got {order} for {window}")
    x = np.asarray(x)
    frames = x.shape[axis]
    window = min(window, frames if frames % 2 else frames - 1)
    if window <= order:
        return x.copy()
    return savgol_filter(x, window, order, axis=axis, mode="interp").astype(x.dtype, copy=False)
