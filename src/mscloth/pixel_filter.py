"""The quadratic B-spline pixel filter as a quantile function, per axis of a pixel sample:
``clothpath``'s tent ``uv_filter`` and the footprint estimator place a camera sample's
shading point by it, so that a stratified pixel sampler stratifies the filter too (the
tent's own quantile is Mitsuba's ``mi.warp.interval_to_tent``)."""
from __future__ import annotations

import drjit as dr


def quadratic_bspline_quantile(u):
    """The quantile at ``u`` in [0, 1] of the quadratic B-spline on [-3/2, 3/2] (box x tent,
    a pixel's box filter convolved with a tent of one pixel's radius): a pixel sample placed
    by it keeps its stratum's order, so a stratified sampler stratifies the filter. Tails:
    CDF (x + 3/2)^3 / 6 below -1/2 (and its mirror); between, three Newton steps on
    CDF(x) = 1/2 + 3x/4 - x^3/3, whose slope stays in [1/2, 3/4]."""
    lower = u < 1.0 / 6.0
    upper = u > 5.0 / 6.0
    tail = dr.cbrt(6.0 * dr.select(upper, 1.0 - u, u))
    x = (u - 0.5) * (4.0 / 3.0)
    for _ in range(3):
        x = x - (0.5 + 0.75 * x - x * x * x * (1.0 / 3.0) - u) / (0.75 - x * x)
    x = dr.clip(x, -0.5, 0.5)
    return dr.select(lower, tail - 1.5, dr.select(upper, 1.5 - tail, x))
