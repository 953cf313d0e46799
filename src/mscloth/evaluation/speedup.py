"""The equal-error speed-up of ``mscloth compare`` from two convergence curves, and how far a
region's speed-up can be trusted.

For each region: the time brute force needs to reach multi-scale's relMSE at
its chosen spp, read off brute force's relMSE-vs-seconds curve, interpolated linearly in
log-log between the two points around the first crossing, divided by multi-scale's
seconds. When brute force never gets down to that error (or is already below it at its
first point), the time is extrapolated from its last (first) point with the Monte Carlo
slope -1 (error ~ 1/time) and flagged ``extrapolated: true``. A region of fewer than
:data:`MIN_REGION_PIXELS` pixels gets a warning beside its speed-up, on the terminal and in
the report (:func:`few_pixels_warning`).
"""
from __future__ import annotations

import math

import numpy as np

#: Least pixels in a region for its speed-up to mean something. A region's relMSE is the mean
#: of N per-pixel squared errors; with Gaussian pixel noise each is a scaled chi-square with
#: relative standard deviation sqrt(2), so the mean's relative standard error is sqrt(2/N)
#: (independent pixels; cloth highlights' heavier tails only make it larger). The speed-up is
#: a ratio of two such estimates (multi-scale's relMSE and brute force's, error ~ 1/time),
#: so its relative standard error is about sqrt(2/N + 2/N) = 2/sqrt(N): 10 % at 400 pixels.
SPEEDUP_RELATIVE_ERROR = 0.10
MIN_REGION_PIXELS = math.ceil((2.0 / SPEEDUP_RELATIVE_ERROR) ** 2)


def speedup_relative_error(pixels: int) -> float:
    """About the relative standard error of a region's speed-up: 2/sqrt(pixels) (see
    :data:`MIN_REGION_PIXELS`)."""
    return 2.0 / math.sqrt(max(pixels, 1))


def few_pixels_warning(pixels: int) -> str | None:
    """Why a region of ``pixels`` pixels gives no meaningful speed-up, or None when it has
    enough (:data:`MIN_REGION_PIXELS`)."""
    if pixels >= MIN_REGION_PIXELS:
        return None
    return (f"only {pixels} pixels (fewer than {MIN_REGION_PIXELS}): its speed-up has a relative standard "
            f"error of about {100 * speedup_relative_error(pixels):.0f} % (2/sqrt(pixels)); "
            "render at a larger --res")


def equal_error_time(seconds, errors, target: float) -> tuple[float, bool]:
    """Seconds a method needs to reach error ``target``, from its (seconds, error) curve.

    Linear interpolation in log-log between the points around the first crossing below
    ``target``; if the curve never gets there (or starts below it), extrapolation from
    its last (first) point with slope -1 (error ~ 1/time). Returns (seconds, extrapolated).
    Any cost that grows along the curve will do for ``seconds``: with sample counts it gives
    the samples a method needs to reach ``target``.
    """
    t = np.asarray(seconds, dtype=np.float64)
    e = np.asarray(errors, dtype=np.float64)
    if t.size == 0 or t.size != e.size:
        raise ValueError("need a non-empty curve with as many errors as times")
    if not (target > 0 and np.all(t > 0) and np.all(e > 0)):
        raise ValueError("times, errors and the target error must be positive")
    order = np.argsort(t, kind="stable")
    t, e = t[order], e[order]
    below = np.flatnonzero(e <= target)
    if below.size == 0:
        return float(t[-1] * e[-1] / target), True
    i = int(below[0])
    if i == 0:
        return float(t[0] * e[0] / target), True
    lt0, lt1 = math.log(t[i - 1]), math.log(t[i])
    le0, le1 = math.log(e[i - 1]), math.log(e[i])
    frac = (math.log(target) - le0) / (le1 - le0)
    return float(math.exp(lt0 + frac * (lt1 - lt0))), False


def closest_in_time(seconds, target: float) -> int:
    """Index of the curve point whose time is closest to ``target`` (in log time)."""
    t = np.asarray(seconds, dtype=np.float64)
    return int(np.argmin(np.abs(np.log(t) - math.log(target))))


def time_at(spp: float, spps, seconds) -> float:
    """A render's seconds at ``spp`` samples per pixel from renders of the same frame at
    ``spps`` (two or more counts) taking ``seconds``: a fixed cost per render (tracing the
    kernel, reading the image back) and a cost per sample, linear between the two measured
    counts around ``spp``, and beyond the measured ones on the line through the nearest two.
    A negative slope (timing noise between two close counts) counts as none."""
    n = np.asarray(spps, dtype=np.float64)
    t = np.asarray(seconds, dtype=np.float64)
    order = np.argsort(n, kind="stable")
    if n.size < 2 or n.size != t.size or np.any(np.diff(n[order]) == 0):
        raise ValueError(f"need two or more different sample counts with a time each, got {list(spps)}")
    n, t = n[order], t[order]
    i = int(np.clip(np.searchsorted(n, spp), 1, n.size - 1))
    per_sample = max((t[i] - t[i - 1]) / (n[i] - n[i - 1]), 0.0)
    return float(t[i - 1] + per_sample * (spp - n[i - 1]))
