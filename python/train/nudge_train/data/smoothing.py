"""Trajectory smoothing with the symmetric exponential moving average of Thiemann, Treiber and
Kesting (2008), and the derivatives of a smoothed trajectory.

The filter (Thiemann, Treiber & Kesting, "Estimating acceleration and lane-changing dynamics
from Next Generation Simulation trajectory data", Transp. Res. Rec. 2088, 2008): a signal
``x_k`` sampled every ``dt`` seconds becomes

    x̂_i = Σ_{k=i-D_i}^{i+D_i} x_k exp(-|i-k| dt / Δ)  /  Σ_{k=i-D_i}^{i+D_i} exp(-|i-k| dt / Δ)

with the smoothing width Δ (s) and the half-window D_i = min(round(3Δ/dt), i, N-1-i): the kernel
is cut at three widths and, near either end of the trajectory, truncated symmetrically so that
the window stays centred on sample i (the first and last samples are kept as they are). The
window being symmetric, a straight line passes unchanged everywhere, the ends included.

Derivatives (:func:`smooth_derivatives`) are central differences of the smoothed signal (one-sided
at the ends), each smoothed again with its own width, as in the paper (speed from smoothed
positions, acceleration from smoothed speeds).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["SmoothingWidths", "smooth_derivatives", "tte_smooth"]


def tte_smooth(x: np.ndarray, dt: float, width_s: float) -> np.ndarray:
    """The symmetric exponential moving average of ``x`` [N] sampled every ``dt`` s with
    smoothing width ``width_s`` (s), kernel cut at 3 widths and truncated symmetrically at the
    ends (see the module docstring). ``width_s`` 0 returns a copy of ``x``.

    Raises:
        ValueError: ``x`` not one-dimensional or holding a non-finite value; ``dt`` not positive
        and finite; ``width_s`` negative or not finite.
    """
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 1:
        raise ValueError(f"tte_smooth: expected a 1-D signal, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"tte_smooth: non-finite sample at index {int(np.flatnonzero(~np.isfinite(x))[0])}")
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"tte_smooth: dt must be positive and finite, got {dt}")
    if not (np.isfinite(width_s) and width_s >= 0):
        raise ValueError(f"tte_smooth: width_s must be >= 0 and finite, got {width_s}")
    n = x.shape[0]
    if width_s == 0 or n < 3:
        return x.copy()
    d_max = int(round(3.0 * width_s / dt))
    idx = np.arange(n)
    half = np.minimum(np.minimum(idx, n - 1 - idx), d_max)
    num = x.copy()
    den = np.ones(n)
    for j in range(1, d_max + 1):
        w = np.exp(-j * dt / width_s)
        use = half >= j  # the window of sample i reaches i-j and i+j
        i = idx[use]
        num[i] += w * (x[i - j] + x[i + j])
        den[i] += 2.0 * w
    return num / den


@dataclass(frozen=True)
class SmoothingWidths:
    """Smoothing widths (s) of a trajectory and of each derivative: ``position`` for the
    positions, ``speed`` for the central differences of the smoothed positions, ``accel`` for
    those of the smoothed speeds, ``jerk`` for those of the smoothed accelerations. 0 disables a
    stage. Peak jerk in particular depends on these widths: a report quotes them. The defaults are
    those of the human lane-change reference (docs/results/human_lane_changes.md says why)."""

    position: float = 0.5
    speed: float = 0.25
    accel: float = 0.25
    jerk: float = 0.25

    def validate(self) -> SmoothingWidths:
        """Self, or ValueError naming the width that is negative or not finite."""
        for name in ("position", "speed", "accel", "jerk"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"SmoothingWidths.{name} must be >= 0 and finite (s), got {v}")
        return self


def smooth_derivatives(x: np.ndarray, dt: float, widths: SmoothingWidths = SmoothingWidths()) -> np.ndarray:
    """Smoothed signal and its first three derivatives, [4, N]: position (m), speed (m/s),
    acceleration (m/s²) and jerk (m/s³) for positions ``x`` [N] (m) sampled every ``dt`` s.

    Each derivative is the central difference (one-sided at the ends) of the previous smoothed
    row, smoothed with its own width (:class:`SmoothingWidths`).

    Raises:
        ValueError: as :func:`tte_smooth`, or fewer than 2 samples.
    """
    widths.validate()
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 1 or x.shape[0] < 2:
        raise ValueError(f"smooth_derivatives: expected a 1-D signal of >= 2 samples, got shape {x.shape}")
    out = np.empty((4, x.shape[0]))
    out[0] = tte_smooth(x, dt, widths.position)
    for k, w in enumerate((widths.speed, widths.accel, widths.jerk), start=1):
        out[k] = tte_smooth(np.gradient(out[k - 1], dt), dt, w)
    return out
