"""The equal-error speed-up of ``mscloth compare`` from two convergence curves, and how far a
region's speed-up can be trusted.

For each region: the samples per pixel brute force needs to reach multi-scale's error at
its chosen spp, read off brute force's error-vs-spp curve, interpolated linearly in log-log
between the two points around the first crossing; their time, linear between brute force's
renders at the counts around it (:func:`time_at`); over multi-scale's seconds. When brute
force never gets down to that error, the count is extrapolated from its last point with its
last stretch's slope or the Monte Carlo slope -1 (error ~ 1/spp), whichever is steeper:
brute force's stratified pixel samples often converge faster than 1/spp, and assuming they
slow down at once would flatter multi-scale. When brute force is already below that error
at its first point, slope -1 backwards. Either is flagged ``extrapolated: true``.

The errors are each method's own: relMSE against the reference minus the reference's own
noise (:class:`ReferenceNoise`), which every image's relMSE contains alike. Without that
subtraction a region whose multi-scale error is near the reference's noise measures the
reference, not the renderer. A region of fewer than
:data:`MIN_REGION_PIXELS` pixels gets a warning beside its speed-up, on the terminal and in
the report (:func:`few_pixels_warning`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

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


#: Standard errors by which an error must exceed the reference's noise to count as measured.
RESOLVED_STANDARD_ERRORS = 3.0


@dataclass(frozen=True)
class ReferenceNoise:
    """The reference's own noise in one region: the relMSE it adds to every image's relMSE,
    and the standard error of subtracting it.

    An image independent of the reference has E[(img - ref)^2] = E[(img - truth)^2] + Var(ref):
    relMSE against the reference is the image's own error plus ``relmse``, the same for both
    methods. ``relmse`` is estimated per pixel from the reference's two independent halves
    (:mod:`.metrics`); its region mean and the reference's realised noise each have a standard
    error of std(per-pixel estimate) / sqrt(pixels), so their difference about sqrt(2) times
    that: ``standard_error``."""

    relmse: float
    standard_error: float

    @classmethod
    def of_region(cls, per_pixel, mask) -> "ReferenceNoise":
        """From the per-pixel relative variance of the reference's mean and a region's mask."""
        values = np.asarray(per_pixel, np.float64)[np.asarray(mask, bool)]
        if values.size == 0:
            raise ValueError("empty region mask")
        spread = float(values.std(ddof=1)) if values.size > 1 else float(values[0])
        return cls(float(values.mean()), math.sqrt(2.0) * spread / math.sqrt(values.size))

    @property
    def resolution(self) -> float:
        """The smallest own error told apart from none: :data:`RESOLVED_STANDARD_ERRORS`
        standard errors (a tiny positive number when the reference is exact)."""
        return max(RESOLVED_STANDARD_ERRORS * self.standard_error, 1e-30)

    def own_error(self, relmse: float) -> float | None:
        """An image's own error, ``relmse`` (against the reference) minus the reference's
        noise, or None when that is within :attr:`resolution` of nothing."""
        own = relmse - self.relmse
        return own if own >= self.resolution else None


def equal_error_time(seconds, errors, target: float) -> tuple[float, bool]:
    """Seconds a method needs to reach error ``target``, from its (seconds, error) curve.

    Linear interpolation in log-log between the points around the first crossing below
    ``target``. If the curve never gets there, extrapolation from its last point with the
    slope of its last stretch or -1 (error ~ 1/time), whichever is steeper; if it starts
    below, from its first point with slope -1. Returns (seconds, extrapolated).
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
        slope = -1.0
        if t.size >= 2 and t[-1] > t[-2]:
            slope = min(slope, math.log(e[-1] / e[-2]) / math.log(t[-1] / t[-2]))
        return float(t[-1] * (e[-1] / target) ** (-1.0 / slope)), True
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
