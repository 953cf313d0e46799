"""Residual summed-area tables (SAT) over one periodic tile, with O(1) periodic queries.

Storage (per channel c of an image ``v`` of shape (C, H, W)):

    mean[c]        = mean of v[c] (float64)
    sat[c, y, x]   = sum_{y' < y, x' < x} (v[c, y', x'] - mean[c])   (float32, shape (C, H+1, W+1))

accumulated in float64 and stored as float32. Subtracting the mean keeps the stored partial
sums small (sat[c, H, W] ~ 0), so float32 storage loses far less than a plain SAT whose
corner values grow like H*W*mean.

Coordinates are texel units: x along columns (0..W), y along rows (0..H); texel (r, c) covers
[c, c+1) x [r, r+1). The image is extended periodically. For a real point (x, y):

    q = floor(x / W), r = x - q*W   (and the same in y)
    F(x, y) = qx*qy*T + qx*S(W, ry) + qy*S(rx, H) + S(rx, ry),   T = S(W, H)

is the integral of the (residual) image over [0, x] x [0, y], with S the SAT bilinearly
interpolated on its (H+1, W+1) grid; bilinear interpolation is exact because the image is
piecewise constant per texel. A rectangle's integral is F(x1,y1) - F(x0,y1) - F(x1,y0) +
F(x0,y0) + mean*area: the cost does not depend on its size.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ResidualSAT", "build_sat", "build_sat_streamed", "rect_sum", "rect_mean", "sat_corner"]

# Largest float64 temporary (bytes) build_sat allocates at once.
_CHUNK_BYTES = 8 << 20


def _residual_cumsum(block: np.ndarray, out: np.ndarray, mean_out: np.ndarray) -> None:
    """block: float64 (c, H, W), modified in place; out: float32 (c, H+1, W+1)."""
    mean = block.mean(axis=(1, 2), dtype=np.float64)
    mean_out[...] = mean
    block -= mean[:, None, None]
    np.cumsum(block, axis=2, out=block)
    # Down the rows: a loop of row additions is ~10x faster than cumsum along axis 1.
    for r in range(1, block.shape[1]):
        np.add(block[:, r], block[:, r - 1], out=block[:, r])
    out[:, 0, :] = 0.0
    out[:, :, 0] = 0.0
    out[:, 1:, 1:] = block


def build_sat(values, out: np.ndarray | None = None):
    """Residual SAT of ``values`` (C, H, W) (or (H, W), treated as C = 1).

    Returns (sat float32 (C, H+1, W+1), mean float64 (C,)). Accumulation is float64, in
    channel chunks of at most ~64 MiB of temporaries. ``out`` may supply the sat array.
    """
    values = np.asarray(values)
    if values.ndim == 2:
        values = values[None]
    if values.ndim != 3 or 0 in values.shape:
        raise ValueError(f"build_sat: expected values of shape (C, H, W), got {values.shape}")
    C, H, W = values.shape
    if out is None:
        out = np.empty((C, H + 1, W + 1), dtype=np.float32)
    elif out.shape != (C, H + 1, W + 1) or out.dtype != np.float32:
        raise ValueError(f"build_sat: out must be float32 {(C, H + 1, W + 1)}, got "
                         f"{out.dtype} {out.shape}")
    mean = np.empty(C, dtype=np.float64)
    step = max(1, _CHUNK_BYTES // (8 * H * W))
    for c0 in range(0, C, step):
        c1 = min(C, c0 + step)
        block = np.array(values[c0:c1], dtype=np.float64, copy=True)
        _residual_cumsum(block, out[c0:c1], mean[c0:c1])
    return out, mean


def build_sat_streamed(n_channels: int, shape, produce, chunk: int = 8, progress=None,
                       out: np.ndarray | None = None):
    """Residual SAT of an image too large to hold in float64 at once.

    ``produce(c0, c1)`` returns float64 values (c1 - c0, H, W) for channels [c0, c1) (it may be
    modified in place). ``progress(done, total)`` is called after each chunk.
    Returns (sat float32 (C, H+1, W+1), mean float64 (C,)).
    """
    H, W = (int(s) for s in shape)
    C = int(n_channels)
    if out is None:
        out = np.empty((C, H + 1, W + 1), dtype=np.float32)
    mean = np.empty(C, dtype=np.float64)
    for c0 in range(0, C, chunk):
        c1 = min(C, c0 + chunk)
        block = np.asarray(produce(c0, c1), dtype=np.float64)
        if block.shape != (c1 - c0, H, W):
            raise ValueError(f"build_sat_streamed: produce({c0}, {c1}) returned shape "
                             f"{block.shape}, expected {(c1 - c0, H, W)}")
        _residual_cumsum(block, out[c0:c1], mean[c0:c1])
        if progress is not None:
            progress(c1, C)
    return out, mean


def _interp(sat: np.ndarray, x: np.ndarray, y: np.ndarray, channels):
    """Bilinear S(x, y), x in [0, W], y in [0, H]; float64. channels None -> (C, ...)."""
    H, W = sat.shape[1] - 1, sat.shape[2] - 1
    i = np.clip(np.floor(x), 0, W - 1).astype(np.int64)
    j = np.clip(np.floor(y), 0, H - 1).astype(np.int64)
    fx = x - i
    fy = y - j
    if channels is None:
        s00 = sat[:, j, i].astype(np.float64)
        s01 = sat[:, j, i + 1].astype(np.float64)
        s10 = sat[:, j + 1, i].astype(np.float64)
        s11 = sat[:, j + 1, i + 1].astype(np.float64)
    else:
        s00 = sat[channels, j, i].astype(np.float64)
        s01 = sat[channels, j, i + 1].astype(np.float64)
        s10 = sat[channels, j + 1, i].astype(np.float64)
        s11 = sat[channels, j + 1, i + 1].astype(np.float64)
    top = s00 + fx * (s01 - s00)
    bot = s10 + fx * (s11 - s10)
    return top + fy * (bot - top)


def sat_corner(sat: np.ndarray, x, y, channels=None) -> np.ndarray:
    """F(x, y): integral of the stored (residual) image over [0, x] x [0, y], periodic.

    channels None: result (C, ...); otherwise ``channels`` broadcasts with x, y.
    """
    H, W = sat.shape[1] - 1, sat.shape[2] - 1
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if channels is not None:
        channels, x, y = np.broadcast_arrays(np.asarray(channels, dtype=np.int64), x, y)
    else:
        x, y = np.broadcast_arrays(x, y)
    qx = np.floor(x / W)
    qy = np.floor(y / H)
    rx = np.clip(x - qx * W, 0.0, W)
    ry = np.clip(y - qy * H, 0.0, H)
    full_x = np.full_like(rx, float(W))
    full_y = np.full_like(ry, float(H))
    if channels is None:
        total = sat[:, H, W].astype(np.float64).reshape((-1,) + (1,) * x.ndim)
    else:
        total = sat[channels, H, W].astype(np.float64)
    return (qx * qy * total + qx * _interp(sat, full_x, ry, channels)
            + qy * _interp(sat, rx, full_y, channels) + _interp(sat, rx, ry, channels))


def rect_sum(sat: np.ndarray, mean, x0, y0, x1, y1, channels=None) -> np.ndarray:
    """Integral of the ORIGINAL image over [x0, x1] x [y0, y1] (texel units, any size, periodic).

    ``sat``/``mean`` come from :func:`build_sat` (a plain SAT works with mean = 0).
    Rectangles broadcast; with ``channels`` None the result has shape rect_shape + (C,),
    otherwise ``channels`` (channel indices) broadcasts with the rectangles and selects one
    channel per rectangle. float64.
    """
    mean = np.asarray(mean, dtype=np.float64).reshape(-1)
    x0, y0, x1, y1 = (np.asarray(a, dtype=np.float64) for a in (x0, y0, x1, y1))
    if np.any(x1 < x0) or np.any(y1 < y0):
        raise ValueError("rect_sum: expected x0 <= x1 and y0 <= y1")
    area = (x1 - x0) * (y1 - y0)
    res = (sat_corner(sat, x1, y1, channels) - sat_corner(sat, x0, y1, channels)
           - sat_corner(sat, x1, y0, channels) + sat_corner(sat, x0, y0, channels))
    if channels is None:
        res = np.moveaxis(res, 0, -1)
        return res + mean * area[..., None]
    return res + mean[np.asarray(channels, dtype=np.int64)] * area


def rect_mean(sat: np.ndarray, mean, x0, y0, x1, y1, channels=None) -> np.ndarray:
    """:func:`rect_sum` divided by the rectangle's area (area must be > 0)."""
    x0, y0, x1, y1 = (np.asarray(a, dtype=np.float64) for a in (x0, y0, x1, y1))
    area = (x1 - x0) * (y1 - y0)
    s = rect_sum(sat, mean, x0, y0, x1, y1, channels)
    return s / (area[..., None] if channels is None else area)


@dataclass(frozen=True, eq=False)
class ResidualSAT:
    """A residual SAT and its per-channel means (see the module docstring)."""

    sat: np.ndarray     # float32 (C, H+1, W+1)
    mean: np.ndarray    # float64 (C,)

    @classmethod
    def build(cls, values) -> "ResidualSAT":
        return cls(*build_sat(values))

    @property
    def channels(self) -> int:
        return int(self.sat.shape[0])

    @property
    def resolution(self) -> tuple[int, int]:
        return int(self.sat.shape[1]) - 1, int(self.sat.shape[2]) - 1

    @property
    def nbytes(self) -> int:
        return int(self.sat.nbytes + self.mean.nbytes)

    def rect_sum(self, x0, y0, x1, y1, channels=None) -> np.ndarray:
        return rect_sum(self.sat, self.mean, x0, y0, x1, y1, channels)

    def rect_mean(self, x0, y0, x1, y1, channels=None) -> np.ndarray:
        return rect_mean(self.sat, self.mean, x0, y0, x1, y1, channels)
