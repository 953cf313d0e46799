"""Cloth maps of a woven fabric from a drawdown: yarn geometry, fibre twist, gaps, colours.

Geometry (our reading of DESIGN §5, not a quote of the paper):

* The tile holds exactly one repeat of the drawdown (shape (n_weft, n_warp)). Warp end j is
  the column band u in [j/n_warp, (j+1)/n_warp) and runs along +v; weft pick i is the row band
  v in [i/n_weft, (i+1)/n_weft) and runs along +u. Crossing (i, j) is at the centre of both
  bands. The tile is taken to be physically square, so u and v (and heights) share one unit,
  the tile width; H and W only set the sampling.
* A yarn's width is ``yarn_width`` times its thread spacing (1/n_warp for warp, 1/n_weft for
  weft). A yarn's centreline height moves between +A (over) and -A (under) at successive
  crossing centres by cosine interpolation (C1: zero slope at every crossing), with
  A = yarn_height/2 * its own spacing. Across the yarn an elliptical cross-section with
  semi-axes (half-width, A) adds A*sqrt(1 - s^2), s = across-offset / half-width in [-1, 1].
  Where both yarns cover a texel the one with the larger surface height is visible.
* Gaps (texels outside both yarns) get height -2*max(A_warp, A_weft), the underside of the
  lowest yarn, so holes read as depressions in the normal map.
* Fibre tangent: the yarn axis a = normalize(along + slope*z) (slope analytic from the
  centreline) rotated about the cross-section normal n_y = normalize(s*across + sqrt(1-s^2)*z)
  by the twist angle psi: t = normalize(cos(psi)*a + sin(psi)*(n_y x a)). The handedness of
  this formula does not depend on the yarn's direction, so warp and weft get the same twist:
  psi > 0 is an S twist (left-handed helix: on a vertical yarn seen from the front the surface
  fibres run like the middle stroke of "S", "\\"), psi < 0 a Z twist ("/"), like real spun
  yarns of one twist direction used for both warp and weft.
* In gaps the tangent is the untwisted axis of the nearer yarn (a valid unit vector; the
  gap map masks it anyway).

Everything is a periodic function of (u, v) sampled at texel centres, so the tile is seamless.
"""
from __future__ import annotations

import math
from numbers import Integral, Real
from typing import Any

import numpy as np

from ..errors import ParameterError
from ..patterns.weaves import validate_drawdown
from .cloth_maps import ClothMaps

MAX_RESOLUTION = 16384
MIN_TEXELS_PER_THREAD = 2


def _real_in(name: str, value: Any, lo: float, hi: float, lo_open: bool, hi_open: bool) -> float:
    """Return ``value`` as a float inside the stated interval, or raise ParameterError."""
    interval = f"{'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
    if isinstance(value, bool) or not isinstance(value, Real):
        raise ParameterError(f"{name} must be a real number in {interval}, got {value!r}")
    x = float(value)
    below = x <= lo if lo_open else x < lo
    above = x >= hi if hi_open else x > hi
    if math.isnan(x) or below or above:
        raise ParameterError(f"{name} must be in {interval}, got {value!r}")
    return x


def _resolution(resolution: Any, n_weft: int, n_warp: int) -> tuple[int, int]:
    """Parse an int (square) or an (H, W) pair; each side needs a few texels per thread."""
    if isinstance(resolution, Integral) and not isinstance(resolution, bool):
        pair = (int(resolution), int(resolution))
    elif (isinstance(resolution, (tuple, list)) and len(resolution) == 2
          and all(isinstance(n, Integral) and not isinstance(n, bool) for n in resolution)):
        pair = (int(resolution[0]), int(resolution[1]))
    else:
        raise ParameterError(f"resolution must be an int or an (H, W) pair of ints, "
                             f"got {resolution!r}")
    for side, n, threads, kind in (("H", pair[0], n_weft, "weft picks"),
                                   ("W", pair[1], n_warp, "warp ends")):
        lo = MIN_TEXELS_PER_THREAD * threads
        if not lo <= n <= MAX_RESOLUTION:
            raise ParameterError(f"resolution {side} must be in [{lo}, {MAX_RESOLUTION}] "
                                 f"({MIN_TEXELS_PER_THREAD} texels for each of the {threads} "
                                 f"{kind}), got {n}")
    return pair


def _colors(name: str, colors: Any, count: int) -> np.ndarray:
    """Return (count, 3) float64 colours in [0, 1]; None means white, one RGB is broadcast."""
    if colors is None:
        return np.ones((count, 3))
    try:
        arr = np.asarray(colors, dtype=np.float64)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} must be an RGB triple or a ({count}, 3) array of "
                             f"floats in [0, 1], got {colors!r}") from None
    if arr.shape == (3,):
        arr = np.broadcast_to(arr, (count, 3))
    if arr.shape != (count, 3):
        raise ParameterError(f"{name} must be an RGB triple or a ({count}, 3) array of "
                             f"floats in [0, 1], got shape {arr.shape}")
    if not np.all(np.isfinite(arr)) or arr.min() < 0 or arr.max() > 1:
        raise ParameterError(f"{name} values must be in [0, 1], got range "
                             f"[{arr.min():g}, {arr.max():g}]")
    return np.array(arr)


def _band(pos: np.ndarray, n: int, half_width: float) -> tuple[np.ndarray, np.ndarray]:
    """Thread index and across-offset s (offset / half-width) of positions in thread units."""
    index = np.floor(pos)
    s = (pos - index - 0.5) / half_width
    return index.astype(np.int64) % n, s


def _crossing_curve(pos: np.ndarray, n: int) -> tuple[np.ndarray, ...]:
    """Neighbouring crossing indices, cosine weight and its derivative along a yarn.

    ``pos`` is the position along the yarn in units of the crossing spacing (tile coordinate
    times ``n``). Crossing k is centred at pos = k + 0.5; the weight goes 0 -> 1 from crossing
    k0 to k1 = k0 + 1 (indices wrapped, which is what makes the tile periodic).
    """
    f = pos - 0.5
    k = np.floor(f)
    t = f - k
    k0 = k.astype(np.int64) % n
    weight = 0.5 - 0.5 * np.cos(np.pi * t)
    # d(weight)/d(tile coordinate) = d(weight)/dt * n.
    dweight = 0.5 * np.pi * np.sin(np.pi * t) * n
    return k0, (k0 + 1) % n, weight, dweight


def _twisted_tangent(along: np.ndarray, across: np.ndarray, slope: np.ndarray, s: np.ndarray,
                     psi: float) -> tuple[np.ndarray, np.ndarray]:
    """(twisted fibre tangent, yarn axis), both (H, W, 3) unit, see module docstring."""
    z = np.array([0.0, 0.0, 1.0])
    axis = along + slope[..., None] * z
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    sc = np.clip(s, -1.0, 1.0)[..., None]
    n_y = sc * across + np.sqrt(1.0 - sc * sc) * z
    n_y /= np.linalg.norm(n_y, axis=-1, keepdims=True)
    t = math.cos(psi) * axis + math.sin(psi) * np.cross(n_y, axis)
    t /= np.linalg.norm(t, axis=-1, keepdims=True)
    return t, axis


def _height_normal(height: np.ndarray) -> np.ndarray:
    """Unit normals (z > 0) of a periodic height field by central differences."""
    h, w = height.shape
    dhdu = (np.roll(height, -1, axis=1) - np.roll(height, 1, axis=1)) * (w / 2.0)
    dhdv = (np.roll(height, -1, axis=0) - np.roll(height, 1, axis=0)) * (h / 2.0)
    n = np.stack([-dhdu, -dhdv, np.ones_like(height)], axis=-1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def woven_maps(drawdown: Any, resolution: int | tuple[int, int] = (128, 128), *,
               yarn_width: float = 0.8, yarn_height: float = 0.35,
               fibre_twist_deg: float = 30.0, warp_colors: Any = None,
               weft_colors: Any = None) -> ClothMaps:
    """Build the maps of one seamless tile of a woven fabric (geometry: module docstring).

    Args:
        drawdown: 2-D bools (n_weft, n_warp), True where the warp end is over the weft pick.
        resolution: (H, W) texels, or one int for a square tile; at least 2 texels per thread.
        yarn_width: yarn width / thread spacing, in (0, 1]. Sampling at texel centres, the
            gap fraction of the tile is (1 - yarn_width)^2 up to about one texel per thread.
        yarn_height: peak-to-peak centreline undulation / thread spacing, in (0, 2].
        fibre_twist_deg: fibre angle to the yarn axis in degrees, [-90, 90]; > 0 is an S
            twist, < 0 a Z twist.
        warp_colors, weft_colors: linear RGB in [0, 1], one triple for all or one per thread
            ((n_warp, 3) / (n_weft, 3)); default white.

    Yarn ids: warp end j -> j, weft pick i -> n_warp + i, gap -> -1.
    """
    dd = validate_drawdown(drawdown)
    n_weft, n_warp = dd.shape
    H, W = _resolution(resolution, n_weft, n_warp)
    w = _real_in("yarn_width", yarn_width, 0.0, 1.0, lo_open=True, hi_open=False)
    yh = _real_in("yarn_height", yarn_height, 0.0, 2.0, lo_open=True, hi_open=False)
    twist = _real_in("fibre_twist_deg", fibre_twist_deg, -90.0, 90.0, False, False)
    warp_rgb = _colors("warp_colors", warp_colors, n_warp)
    weft_rgb = _colors("weft_colors", weft_colors, n_weft)
    psi = math.radians(twist)

    # Texel-centre coordinates in thread units: u * n_warp counts warp ends, v * n_weft picks.
    pos_u = (np.arange(W) + 0.5) / W * n_warp
    pos_v = (np.arange(H) + 0.5) / H * n_weft
    amp_warp = 0.5 * yh / n_warp  # A, in tile widths
    amp_weft = 0.5 * yh / n_weft
    up = np.where(dd, 1.0, -1.0)  # +1 where the warp is over

    # Warp end j: column band, centreline interpolated along v between weft crossings.
    j, s_warp = _band(pos_u, n_warp, 0.5 * w)                     # (W,)
    i0, i1, wv, dwv = _crossing_curve(pos_v, n_weft)             # (H,)
    h0 = amp_warp * up[i0[:, None], j[None, :]]
    h1 = amp_warp * up[i1[:, None], j[None, :]]
    centre_warp = h0 + (h1 - h0) * wv[:, None]
    slope_warp = (h1 - h0) * dwv[:, None]
    bulge_warp = amp_warp * np.sqrt(np.clip(1.0 - s_warp**2, 0.0, None))
    surf_warp = centre_warp + bulge_warp[None, :]

    # Weft pick i: row band, centreline interpolated along u between warp crossings;
    # the weft is over exactly where the warp is under.
    i, s_weft = _band(pos_v, n_weft, 0.5 * w)                     # (H,)
    j0, j1, wu, dwu = _crossing_curve(pos_u, n_warp)             # (W,)
    g0 = -amp_weft * up[i[:, None], j0[None, :]]
    g1 = -amp_weft * up[i[:, None], j1[None, :]]
    centre_weft = g0 + (g1 - g0) * wu[None, :]
    slope_weft = (g1 - g0) * dwu[None, :]
    bulge_weft = amp_weft * np.sqrt(np.clip(1.0 - s_weft**2, 0.0, None))
    surf_weft = centre_weft + bulge_weft[:, None]

    in_warp = np.broadcast_to((np.abs(s_warp) <= 1.0)[None, :], (H, W))
    in_weft = np.broadcast_to((np.abs(s_weft) <= 1.0)[:, None], (H, W))
    warp_vis = in_warp & (~in_weft | (surf_warp >= surf_weft))
    weft_vis = in_weft & ~warp_vis
    yarn = warp_vis | weft_vis

    floor = -2.0 * max(amp_warp, amp_weft)
    height = np.where(warp_vis, surf_warp, np.where(weft_vis, surf_weft, floor))

    x_axis = np.array([1.0, 0.0, 0.0])
    y_axis = np.array([0.0, 1.0, 0.0])
    s_warp_2d = np.broadcast_to(s_warp[None, :], (H, W))
    s_weft_2d = np.broadcast_to(s_weft[:, None], (H, W))
    t_warp, axis_warp = _twisted_tangent(y_axis, x_axis, slope_warp, s_warp_2d, psi)
    t_weft, axis_weft = _twisted_tangent(x_axis, y_axis, slope_weft, s_weft_2d, psi)
    # Gap texels: the nearer yarn's axis; distances beyond each yarn's edge in tile widths.
    beyond_warp = (np.abs(s_warp_2d) - 1.0) * (0.5 * w / n_warp)
    beyond_weft = (np.abs(s_weft_2d) - 1.0) * (0.5 * w / n_weft)
    gap_axis = np.where((beyond_warp <= beyond_weft)[..., None], axis_warp, axis_weft)
    tangent = np.where(warp_vis[..., None], t_warp,
                       np.where(weft_vis[..., None], t_weft, gap_axis))

    yarn_id = np.where(warp_vis, j[None, :], np.where(weft_vis, n_warp + i[:, None], -1))
    albedo = np.where(warp_vis[..., None], warp_rgb[j][None, :, :],
                      np.where(weft_vis[..., None], weft_rgb[i][:, None, :], 0.0))

    meta = {
        "generator": "woven",
        "drawdown": dd.astype(np.int8).tolist(),
        "yarn_width": w,
        "yarn_height": yh,
        "fibre_twist_deg": twist,
        "twist": "S" if twist > 0 else ("Z" if twist < 0 else "none"),
        "warp_colors": warp_rgb.tolist(),
        "weft_colors": weft_rgb.tolist(),
    }
    return ClothMaps(tangent=tangent, normal=_height_normal(height), height=height,
                     gap=yarn.astype(np.float32), yarn_id=yarn_id.astype(np.int32),
                     albedo=albedo, meta=meta)


__all__ = ["woven_maps"]
