"""Direction bins on the upper hemisphere (NumPy).

Directions are mapped to the unit square with the *same* formulas as Mitsuba's
``mi.warp.uniform_hemisphere_to_square`` / ``mi.warp.square_to_uniform_hemisphere``
(Shirley-Chiu concentric map of the disk, then the equal-area lift to the hemisphere), so a
Dr.Jit BSDF can use Mitsuba's functions and land in the same bins as these tables.

Bin grid with ``n`` bins per side: bin (a, b) is centred at square coordinates
((a + 0.5)/n, (b + 0.5)/n); its flat index is ``b*n + a`` (a along the square's first
coordinate). The map is equal-area, so every bin covers 2*pi/n^2 sr.

Visibility lookups interpolate bilinearly between the four nearest bin centres, clamped at
the edge bins (:func:`bilinear_bins`), which the BSDF reproduces in Dr.Jit::

    x = p*n - 0.5; i0 = floor(x); f = x - i0; i1 = i0 + 1; clamp i0, i1 to [0, n-1]

The directional D tables are read over the triangle of three of those four (the cell of bin
centres cut along its diagonal, :func:`triangle_bins`): linear as well, at three quarters of
the reads.
"""
from __future__ import annotations

import numpy as np

__all__ = ["bins_for_roughness", "fold_upper", "hemisphere_to_square", "square_to_hemisphere", "bin_centres",
           "bilinear_bins", "triangle_bins", "direction_to_bin"]


def _mulsign(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a * sign(b), using b's sign bit (like ``dr.mulsign``: -0.0 counts as negative)."""
    return np.where(np.signbit(b), -a, a)


def fold_upper(w) -> np.ndarray:
    """Return w or -w, whichever has z >= 0 (the SGGX D is even: D(-h) = D(h))."""
    w = np.asarray(w, dtype=np.float64)
    return np.where(w[..., 2:3] < 0.0, -w, w)


def hemisphere_to_square(w) -> np.ndarray:
    """Unit directions with z >= 0, shape (..., 3) -> square coordinates in [0, 1]^2, (..., 2).

    Mitsuba's ``uniform_hemisphere_to_square``: p = w.xy / sqrt(1 + z), then the inverse
    concentric disk map. Directions below the horizon are not folded here (see
    :func:`fold_upper`); they land outside the square.
    """
    w = np.asarray(w, dtype=np.float64)
    px = w[..., 0] / np.sqrt(w[..., 2] + 1.0)
    py = w[..., 1] / np.sqrt(w[..., 2] + 1.0)
    quadrant_0_or_2 = np.abs(px) > np.abs(py)
    r_sign = np.where(quadrant_0_or_2, px, py)
    r = np.copysign(np.hypot(px, py), r_sign)
    phi = np.arctan2(_mulsign(py, r_sign), _mulsign(px, r_sign))
    t = 4.0 / np.pi * phi
    t = np.where(quadrant_0_or_2, t, 2.0 - t) * r
    a = np.where(quadrant_0_or_2, r, t)
    b = np.where(quadrant_0_or_2, t, r)
    return np.stack([(a + 1.0) * 0.5, (b + 1.0) * 0.5], axis=-1)


def square_to_hemisphere(p) -> np.ndarray:
    """Square coordinates (..., 2) -> unit directions with z >= 0, (..., 3).

    Mitsuba's ``square_to_uniform_hemisphere``: concentric disk map (Dave Cline's variant),
    z = 1 - |d|^2, d *= sqrt(1 + z).
    """
    p = np.asarray(p, dtype=np.float64)
    x = 2.0 * p[..., 0] - 1.0
    y = 2.0 * p[..., 1] - 1.0
    is_zero = (x == 0.0) & (y == 0.0)
    quadrant_1_or_3 = np.abs(x) < np.abs(y)
    r = np.where(quadrant_1_or_3, y, x)
    rp = np.where(quadrant_1_or_3, x, y)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = 0.25 * np.pi * rp / r
    phi = np.where(quadrant_1_or_3, 0.5 * np.pi - phi, phi)
    phi = np.where(is_zero, 0.0, phi)
    dx, dy = r * np.cos(phi), r * np.sin(phi)
    z = 1.0 - (dx * dx + dy * dy)
    s = np.sqrt(np.maximum(z, 0.0) + 1.0)
    return np.stack([dx * s, dy * s, z], axis=-1)


def bin_centres(n: int) -> np.ndarray:
    """Directions of the n*n bin centres, shape (n*n, 3), flat index b*n + a."""
    n = int(n)
    if n < 1:
        raise ValueError(f"bins per side must be >= 1, got {n}")
    c = (np.arange(n) + 0.5) / n
    a, b = np.meshgrid(c, c, indexing="xy")          # a varies along the last axis
    return square_to_hemisphere(np.stack([a.ravel(), b.ravel()], axis=-1))


def bilinear_bins(p_square, n: int):
    """Four bins and bilinear weights around square coordinates ``p_square`` (..., 2).

    Returns (indices int64 (..., 4), weights float64 (..., 4)); weights sum to 1. Order:
    (a0, b0), (a1, b0), (a0, b1), (a1, b1). Coordinates beyond the outer bin centres clamp
    to the edge bins (both neighbours become the same bin).
    """
    p = np.asarray(p_square, dtype=np.float64)
    x = p * n - 0.5
    i0 = np.floor(x)
    f = x - i0
    i0 = i0.astype(np.int64)
    i1 = np.clip(i0 + 1, 0, n - 1)
    i0 = np.clip(i0, 0, n - 1)
    a0, a1, b0, b1 = i0[..., 0], i1[..., 0], i0[..., 1], i1[..., 1]
    fa, fb = f[..., 0], f[..., 1]
    idx = np.stack([b0 * n + a0, b0 * n + a1, b1 * n + a0, b1 * n + a1], axis=-1)
    wts = np.stack([(1 - fa) * (1 - fb), fa * (1 - fb), (1 - fa) * fb, fa * fb], axis=-1)
    return idx, wts


def triangle_bins(p_square, n: int):
    """Three bins and barycentric weights around square coordinates ``p_square`` (..., 2):
    the cell of :func:`bilinear_bins`' four cut along its diagonal from (a0, b0) to (a1, b1),
    the half that holds the point. Interpolates functions linear in the bin coordinates
    exactly, as the four do, and is continuous across cells.

    Returns (indices int64 (..., 3), weights float64 (..., 3)); weights sum to 1. Order:
    (a0, b0), (a1, b0) or (a0, b1) (whichever of fa, fb is larger), (a1, b1). Edges clamp as
    in :func:`bilinear_bins`.
    """
    idx4, _ = bilinear_bins(p_square, n)
    p = np.asarray(p_square, dtype=np.float64)
    x = p * n - 0.5
    f = x - np.floor(x)
    fa, fb = f[..., 0], f[..., 1]
    upper = fa >= fb
    idx = np.stack([idx4[..., 0], np.where(upper, idx4[..., 1], idx4[..., 2]), idx4[..., 3]], axis=-1)
    wts = np.stack([1 - np.maximum(fa, fb), np.abs(fa - fb), np.minimum(fa, fb)], axis=-1)
    return idx, wts


def direction_to_bin(w, n: int) -> np.ndarray:
    """Nearest bin (flat index) of unit directions ``w`` (..., 3), folded to z >= 0."""
    p = hemisphere_to_square(fold_upper(w))
    i = np.clip(np.floor(p * n).astype(np.int64), 0, n - 1)
    return i[..., 1] * n + i[..., 0]


#: (lowest roughness, bins per side): the direction bins a fibre roughness gets by default.
BINS_BY_ROUGHNESS = ((0.2, 16), (0.08, 32), (0.0, 48))


def bins_for_roughness(alpha: float) -> int:
    """Direction bins per side for fibres of roughness ``alpha``: the fibre NDF's lobe is
    about alpha wide in h.t, and the bins must resolve it. Measured on a dense satin at
    alpha 0.1 (``bench/footprint_estimator.py``): 32 bins instead of 16 cut the variance of
    a footprint evaluation 4-10x at 256 texels and more (the residual texels' control
    variate is each texel's binned D; docs/performance-log.md L15)."""
    for lowest, bins in BINS_BY_ROUGHNESS:
        if alpha >= lowest:
            return bins
    return BINS_BY_ROUGHNESS[-1][1]
