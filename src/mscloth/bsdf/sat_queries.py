"""Dr.Jit side of the summed-area tables: O(1) integrals over any texel rectangle of a
periodic tile, and the direction-bin lookups that go with them.

Tables come from :mod:`mscloth.precompute` as *residual* SATs on the (H+1) x (W+1) grid
of texel corners: sat[c, y, x] = sum over texels y' < y, x' < x of (v - mean_c). The
integral of a piecewise-constant image over a rectangle with real corners is bilinear in
the corner coordinates, so bilinear lookups give exact fractional-texel integrals.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np


def flat_array(values: np.ndarray):
    """A flat float32 Dr.Jit array of ``values`` that ``dr.gather`` reads, in every variant
    (a JIT array in llvm/cuda, a dynamic array in scalar variants)."""
    values = np.ascontiguousarray(np.asarray(values, dtype=np.float32).ravel())
    return mi.TensorXf(values).array


def gather(source, index, active=True):
    """``source[index]`` per lane (0 where not ``active``), in JIT and scalar variants."""
    if dr.is_jit_v(mi.Float):
        return dr.gather(mi.Float, source, index, active)
    return source[int(index)] if active else 0.0


class ResidualSATs:
    """``C`` residual SATs of one tile, flat in Dr.Jit memory, queried per lane."""

    def __init__(self, sat: np.ndarray, mean: np.ndarray):
        sat = np.asarray(sat, dtype=np.float32)
        if sat.ndim == 2:
            sat = sat[None]
        self.channels, rows, cols = sat.shape
        self.H, self.W = rows - 1, cols - 1
        self.data = flat_array(sat)
        self.mean = flat_array(np.asarray(mean, dtype=np.float64))
        self.total = flat_array(sat[:, self.H, self.W])  # ~0 by construction
        # The last column (x = W) and last row (y = H) alone: the periodic decomposition
        # reads them at every corner, and 1-D interpolation needs 2 reads instead of 4.
        self.last_col = flat_array(sat[:, :, self.W])
        self.last_row = flat_array(sat[:, self.H, :])

    def nbytes(self) -> int:
        return 4 * (len(self.data) + len(self.last_col) + len(self.last_row) + 2 * self.channels)

    def _lookup(self, base, x, y):
        """Bilinear value of the channel at flat offset ``base`` at grid coords 0<=x<=W, 0<=y<=H."""
        x = dr.clip(x, 0.0, float(self.W))
        y = dr.clip(y, 0.0, float(self.H))
        ix = dr.minimum(mi.UInt32(dr.floor(x)), self.W - 1)
        iy = dr.minimum(mi.UInt32(dr.floor(y)), self.H - 1)
        fx = x - mi.Float(ix)
        fy = y - mi.Float(iy)
        stride = self.W + 1
        i00 = base + iy * stride + ix
        v00 = gather(self.data, i00)
        v01 = gather(self.data, i00 + 1)
        v10 = gather(self.data, i00 + stride)
        v11 = gather(self.data, i00 + stride + 1)
        return dr.lerp(dr.lerp(v00, v01, fx), dr.lerp(v10, v11, fx), fy)

    def _lookup_1d(self, data, channel, n, t, active):
        """Linear interpolation of a per-channel 1-D table of n + 1 values at 0 <= t <= n;
        lanes that do not need it (``active`` false: a factor of zero) skip the reads."""
        t = dr.clip(t, 0.0, float(n))
        i = dr.minimum(mi.UInt32(dr.floor(t)), n - 1)
        f = t - mi.Float(i)
        base = channel * (n + 1) + i
        return dr.lerp(gather(data, base, active), gather(data, base + 1, active), f)

    def _cumulative(self, base, total, x, y, channel=None):
        """Residual integral over [0, x] x [0, y] of the periodically repeated tile."""
        W, H = float(self.W), float(self.H)
        qx = dr.floor(x / W)
        qy = dr.floor(y / H)
        rx = dr.clip(x - qx * W, 0.0, W)
        ry = dr.clip(y - qy * H, 0.0, H)
        # Footprints inside one tile have qx = qy = 0 at every corner: no edge reads.
        return (qx * qy * total + qx * self._lookup_1d(self.last_col, channel, self.H, ry, qx != 0.0)
                + qy * self._lookup_1d(self.last_row, channel, self.W, rx, qy != 0.0) + self._lookup(base, rx, ry))

    def rect_integral(self, channel, x0, y0, x1, y1):
        """Integral of the original values of ``channel`` (int or per-lane UInt32) over the
        texel rectangle [x0, x1] x [y0, y1] (any size, any position: periodic)."""
        channel = mi.UInt32(channel)
        base = channel * ((self.H + 1) * (self.W + 1))
        total = gather(self.total, channel)
        mean = gather(self.mean, channel)
        residual = (self._cumulative(base, total, x1, y1, channel) - self._cumulative(base, total, x0, y1, channel)
                    - self._cumulative(base, total, x1, y0, channel) + self._cumulative(base, total, x0, y0, channel))
        return residual + mean * (x1 - x0) * (y1 - y0)


def hemisphere_bins(w, n: int):
    """Four direction bins around the upper-hemisphere direction ``w`` and their bilinear
    weights, on the n x n equal-area square grid of :mod:`mscloth.precompute.direction_bins`
    (bin (a, b) centred at ((a + .5)/n, (b + .5)/n), flat index b*n + a; edge bins clamp)."""
    p = mi.warp.uniform_hemisphere_to_square(w)
    x = p.x * n - 0.5
    y = p.y * n - 0.5
    ax = dr.floor(x)
    ay = dr.floor(y)
    fx = x - ax
    fy = y - ay
    a0 = mi.UInt32(dr.clip(ax, 0, n - 1))
    a1 = mi.UInt32(dr.clip(ax + 1, 0, n - 1))
    b0 = mi.UInt32(dr.clip(ay, 0, n - 1))
    b1 = mi.UInt32(dr.clip(ay + 1, 0, n - 1))
    bins = (b0 * n + a0, b0 * n + a1, b1 * n + a0, b1 * n + a1)
    weights = ((1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy)
    return bins, weights
