"""The in-betweening measures of Harvey et al. 2020 (Robust Motion In-betweening), on arrays of the gap's
frames: L2P, L2Q and NPSS, one value per transition, to be averaged (and bootstrapped) over transitions.

- L2P: the mean over the gap's frames of the L2 norm of the difference of all global joint positions,
  each coordinate first standardised (`(p - mean) / std`, statistics given by the caller: Harvey et al.
  take them from the training set);
- L2Q: the same over global joint rotations as unit quaternions, each made to share the hemisphere of
  the real one (q and -q are one rotation);
- NPSS (Gopalakrishnan et al. 2019): per channel, the power spectrum over the gap's frames of the real
  and the made motion, each normalised to sum to 1; the earth mover's distance between the two (the L1
  distance of their cumulative sums), averaged over channels weighted by each channel's share of the real
  motion's total power. 0: the same spectra; it ignores where the motion is, only how it moves.
"""

from __future__ import annotations

import numpy as np


def l2p(made: np.ndarray, real: np.ndarray, mean: np.ndarray, std: np.ndarray) -> np.ndarray:
    """(N,) from positions (N, F, J, 3) and per-coordinate statistics broadcasting to (J, 3)."""
    diff = (np.asarray(made) - np.asarray(real)) / np.asarray(std)
    return np.linalg.norm(diff.reshape(*diff.shape[:2], -1), axis=-1).mean(-1)


def l2q(made: np.ndarray, real: np.ndarray) -> np.ndarray:
    """(N,) from unit quaternions (N, F, J, 4); the made ones turned to the real ones' hemisphere."""
    made, real = np.asarray(made, np.float64), np.asarray(real, np.float64)
    made = np.where((made * real).sum(-1, keepdims=True) < 0, -made, made)
    return np.linalg.norm((made - real).reshape(*made.shape[:2], -1), axis=-1).mean(-1)


def npss(made: np.ndarray, real: np.ndarray) -> np.ndarray:
    """(N,) from channels over time (N, F, C) (global quaternions flattened, as Harvey et al.)."""
    made, real = np.asarray(made, np.float64), np.asarray(real, np.float64)
    power_made = np.abs(np.fft.rfft(made, axis=1)) ** 2  # (N, frequencies, C)
    power_real = np.abs(np.fft.rfft(real, axis=1)) ** 2
    total_made, total_real = power_made.sum(1), power_real.sum(1)  # (N, C)
    tiny = np.finfo(np.float64).tiny
    cdf_made = np.cumsum(power_made / np.maximum(total_made, tiny)[:, None], axis=1)
    cdf_real = np.cumsum(power_real / np.maximum(total_real, tiny)[:, None], axis=1)
    emd = np.abs(cdf_made - cdf_real).sum(1)  # (N, C)
    weight = total_real / np.maximum(total_real.sum(-1, keepdims=True), tiny)
    return (emd * weight).sum(-1)
