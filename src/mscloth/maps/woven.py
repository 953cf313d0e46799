"""Cloth maps of a woven fabric from a drawdown: yarn geometry, fibre twist, gaps, colours.

Geometry (our reading of docs/design.md §5, not a quote of the paper):

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
from numbers import Integral
from typing import Any

import numpy as np

from ..errors import ParameterError
from ..patterns.draft import Draft
from ..patterns.weaves import validate_drawdown
from .cloth_maps import ClothMaps
from .generator_support import height_normal, real_in, srgb_to_linear, tile_resolution

MIN_TEXELS_PER_THREAD = 2


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


def _as_draft(pattern: Any) -> Draft:
    return pattern if isinstance(pattern, Draft) else Draft(validate_drawdown(pattern))


def _tile_resolution(resolution: Any, draft: Draft) -> tuple[int, int]:
    """An int is the width in texels (the height follows the tile's aspect); (H, W) is exact."""
    width_mm, height_mm = draft.size_mm
    return tile_resolution(resolution, height_mm / width_mm, (draft.n_weft, draft.n_warp),
                           MIN_TEXELS_PER_THREAD, ("weft picks", "warp ends"))


def _threads(centres_of: np.ndarray, spacing: np.ndarray, pos: np.ndarray):
    """Thread index and signed offset from its centre (mm) of positions ``pos`` (mm)."""
    edges = np.cumsum(spacing)
    index = np.searchsorted(edges, pos, side="right")
    index = np.minimum(index, len(spacing) - 1)
    return index, pos - centres_of[index]


def _crossings(centres: np.ndarray, period: float, pos: np.ndarray):
    """Neighbouring crossing centres k0 <= pos < k1 (periodic) along a yarn, the cosine
    weight w(pos) going 0 -> 1 from k0 to k1 (zero slope at both) and dw/dpos (per mm)."""
    n = len(centres)
    ext = np.concatenate([[centres[-1] - period], centres, [centres[0] + period]])
    idx = np.clip(np.searchsorted(ext, pos, side="right") - 1, 0, n)
    start, stop = ext[idx], ext[idx + 1]
    t = (pos - start) / (stop - start)
    k0 = (idx - 1) % n
    k1 = idx % n
    weight = 0.5 - 0.5 * np.cos(np.pi * t)
    dweight = 0.5 * np.pi * np.sin(np.pi * t) / (stop - start)
    return k0, k1, weight, dweight


def float_heights(over: np.ndarray, arch: float) -> np.ndarray:
    """Centreline height / A at each crossing of the yarns along axis 0 of ``over`` (+1
    where the yarn is over, -1 under): +-1, except that a run of k > 1 crossings on one side
    rises towards its middle, the m-th (of k) to 1 - arch (1 - 2 sin(pi (m + 1) / (k + 1)))
    in magnitude: a half-sine arch from the crossing before the run to the one after."""
    over = np.asarray(over, dtype=float)
    out = over.copy()
    if arch <= 0.0:
        return out
    n = over.shape[0]
    for col in range(over.shape[1]):
        c = over[:, col]
        if np.all(c == c[0]):
            continue  # never interlaced: flat
        start = int(np.argmax(c != np.roll(c, 1)))  # a run starts here
        m = 0
        while m < n:
            k = 1
            while k < n and c[(start + m + k) % n] == c[(start + m) % n]:
                k += 1
            if k > 1:
                for q in range(k):
                    a = math.sin(math.pi * (q + 1) / (k + 1))
                    out[(start + m + q) % n, col] = c[(start + m) % n] * ((1.0 - arch) + arch * (2.0 * a - 1.0))
            m += k
    return out


def _ply_tangent(axis: np.ndarray, n_y: np.ndarray, along_mm: np.ndarray, across_mm: np.ndarray,
                 side: float, diameter: np.ndarray, mean_spacing: float, ply_count: int,
                 beta: float, psi: float) -> tuple[np.ndarray, np.ndarray]:
    """Fibre tangent and relief of a plied yarn: ``ply_count`` plies wind around the axis at
    ``beta``; their boundaries are stripes along the ply axis, and inside a ply the fibres
    twist the other way by ``psi`` about the ply's own surface normal. Returns (t, q) with q
    in [-1, 1] the position across the ply, for the relief."""
    ply_axis = math.cos(beta) * axis + math.sin(beta) * np.cross(n_y, axis)
    ply_axis /= np.linalg.norm(ply_axis, axis=-1, keepdims=True)
    # Stripes are invariant along the ply axis; one ply per pitch / ply_count along the
    # yarn. The stripe length is rounded to a whole fraction of the mean crossing spacing
    # (at least one stripe per crossing), so the tile is seamless and a tile of repeated
    # drafts gives the same maps as the single one laid side by side.
    pitch = np.pi * diameter / (ply_count * math.tan(beta))
    stripe = mean_spacing / np.maximum(1.0, np.round(mean_spacing / pitch))
    phase = (along_mm - side * across_mm / math.tan(beta)) / stripe
    q = 2.0 * (phase - np.floor(phase)) - 1.0
    across_ply = np.cross(n_y, ply_axis)
    n_p = q[..., None] * across_ply + np.sqrt(1.0 - q * q)[..., None] * n_y
    n_p /= np.linalg.norm(n_p, axis=-1, keepdims=True)
    t = math.cos(psi) * ply_axis - math.sin(psi) * np.cross(n_p, ply_axis)
    return t / np.linalg.norm(t, axis=-1, keepdims=True), q


def woven_maps(pattern: Any, resolution: int | tuple[int, int] = (128, 128), *,
               yarn_width: float | None = None, gap_fraction: float | None = None,
               yarn_height: float = 0.35, profile_exponent: float = 2.0,
               fibre_twist_deg: float = 30.0, ply_count: int = 1, ply_twist_deg: float = 30.0,
               warp_colors: Any = None, weft_colors: Any = None, float_arch: float = 0.0) -> ClothMaps:
    """Build the maps of one seamless tile of a woven fabric (geometry: module docstring).

    Args:
        pattern: a :class:`~mscloth.patterns.draft.Draft`, or a drawdown: 2-D bools
            (n_weft, n_warp), True where the warp end is over the weft pick.
        resolution: texels along u (the height follows the tile's physical aspect), or an
            exact (H, W); at least 2 texels per thread.
        yarn_width: yarn width / thread spacing, in (0, 1], for every thread; default: each
            thread's thickness / spacing from the draft. With uniform spacing and texel-centre
            sampling the gap fraction is (1 - yarn_width)^2 up to about one texel per thread.
        gap_fraction: the wanted fraction of the tile that is holes, in [0, 1); sets
            yarn_width = 1 - sqrt(gap_fraction) (exact for uniform spacing). Not with yarn_width.
        yarn_height: peak-to-peak centreline undulation / yarn width, in (0, 2].
        profile_exponent: cross-section superellipse exponent p in [1, 16]: the surface rises
            A (1 - |s|^p)^(1/p) across the yarn; 2 is an ellipse, larger is flatter.
        fibre_twist_deg: fibre angle to the yarn (or ply) axis in degrees, [-90, 90]; > 0 is an
            S twist, < 0 a Z twist.
        ply_count: plies per yarn, 1 to 8 (1: a single yarn).
        ply_twist_deg: angle of the plies to the yarn axis, in (0, 90) when ply_count > 1.
        warp_colors, weft_colors: *linear* RGB in [0, 1], one triple for all or one per thread;
            default: the draft's sRGB colours, converted to linear.
        float_arch: in [0, 1]; 0 keeps a float (a run of crossings over the other yarn) flat
            at +A, 1 arches it: its crossings rise along a half sine from the crossing
            before the float to the one after (:func:`float_heights`), so its fibres tilt
            through every angle up to the yarn's inclination, as the spines of real floats
            do (Irawan & Marschner 2012). Single crossings (plain weave) are unchanged.

    Yarn ids: warp end j -> j, weft pick i -> n_warp + i, gap -> -1. Heights are in units of
    the tile width; ``meta['tile_size_mm']`` is the tile's (width, height) in millimetres.
    """
    draft = _as_draft(pattern)
    dd = draft.drawdown
    n_weft, n_warp = dd.shape
    H, W = _tile_resolution(resolution, draft)
    if yarn_width is not None and gap_fraction is not None:
        raise ParameterError("give yarn_width or gap_fraction, not both")
    if gap_fraction is not None:
        g = real_in("gap_fraction", gap_fraction, 0.0, 1.0, lo_open=False, hi_open=True)
        yarn_width = 1.0 - math.sqrt(g)
    if yarn_width is not None:
        w = real_in("yarn_width", yarn_width, 0.0, 1.0, lo_open=True, hi_open=False)
        warp_width, weft_width = w * draft.warp_spacing, w * draft.weft_spacing
    else:
        warp_width = np.minimum(draft.warp_thickness, draft.warp_spacing)
        weft_width = np.minimum(draft.weft_thickness, draft.weft_spacing)
    yh = real_in("yarn_height", yarn_height, 0.0, 2.0, lo_open=True, hi_open=False)
    p_exp = real_in("profile_exponent", profile_exponent, 1.0, 16.0, False, False)
    twist = real_in("fibre_twist_deg", fibre_twist_deg, -90.0, 90.0, False, False)
    if isinstance(ply_count, bool) or not isinstance(ply_count, Integral) or not 1 <= ply_count <= 8:
        raise ParameterError(f"ply_count must be an integer in [1, 8], got {ply_count!r}")
    beta = math.radians(real_in("ply_twist_deg", ply_twist_deg, 0.0, 90.0, True, True)) if ply_count > 1 else 0.0
    warp_rgb = _colors("warp_colors", warp_colors, n_warp) if warp_colors is not None else srgb_to_linear(draft.warp_colors)
    weft_rgb = _colors("weft_colors", weft_colors, n_weft) if weft_colors is not None else srgb_to_linear(draft.weft_colors)
    psi = math.radians(twist)

    width_mm, height_mm = draft.size_mm
    warp_centre = np.cumsum(draft.warp_spacing) - 0.5 * draft.warp_spacing
    weft_centre = np.cumsum(draft.weft_spacing) - 0.5 * draft.weft_spacing
    x = (np.arange(W) + 0.5) / W * width_mm      # texel centres, mm
    y = (np.arange(H) + 0.5) / H * height_mm
    up = np.where(dd, 1.0, -1.0)                  # +1 where the warp is over
    arch = real_in("float_arch", float_arch, 0.0, 1.0, False, False)
    warp_level = float_heights(up, arch)          # (picks, ends): warp centreline / A
    weft_level = float_heights(-up.T, arch).T     # weft centreline / A
    amp_warp = 0.5 * yh * warp_width              # centreline amplitude A per thread, mm
    amp_weft = 0.5 * yh * weft_width

    def bulge(amp, s):
        return amp * np.clip(1.0 - np.abs(s) ** p_exp, 0.0, None) ** (1.0 / p_exp)

    # Warp end j: column band, centreline interpolated along v between weft crossings.
    j, dx = _threads(warp_centre, draft.warp_spacing, x)                 # (W,)
    s_warp = dx / (0.5 * warp_width[j])
    i0, i1, wv, dwv = _crossings(weft_centre, height_mm, y)              # (H,)
    a_w = amp_warp[j][None, :]
    h0 = a_w * warp_level[i0[:, None], j[None, :]]
    h1 = a_w * warp_level[i1[:, None], j[None, :]]
    centre_warp = h0 + (h1 - h0) * wv[:, None]
    slope_warp = (h1 - h0) * dwv[:, None]
    surf_warp = centre_warp + bulge(amp_warp[j], s_warp)[None, :]

    # Weft pick i: row band; the weft is over exactly where the warp is under.
    i, dy = _threads(weft_centre, draft.weft_spacing, y)                 # (H,)
    s_weft = dy / (0.5 * weft_width[i])
    j0, j1, wu, dwu = _crossings(warp_centre, width_mm, x)               # (W,)
    a_f = amp_weft[i][:, None]
    g0 = a_f * weft_level[i[:, None], j0[None, :]]
    g1 = a_f * weft_level[i[:, None], j1[None, :]]
    centre_weft = g0 + (g1 - g0) * wu[None, :]
    slope_weft = (g1 - g0) * dwu[None, :]
    surf_weft = centre_weft + bulge(amp_weft[i], s_weft)[:, None]

    in_warp = np.broadcast_to((np.abs(s_warp) <= 1.0)[None, :], (H, W))
    in_weft = np.broadcast_to((np.abs(s_weft) <= 1.0)[:, None], (H, W))
    warp_vis = in_warp & (~in_weft | (surf_warp >= surf_weft))
    weft_vis = in_weft & ~warp_vis
    yarn = warp_vis | weft_vis

    x_axis = np.array([1.0, 0.0, 0.0])
    y_axis = np.array([0.0, 1.0, 0.0])
    s_warp_2d = np.broadcast_to(s_warp[None, :], (H, W))
    s_weft_2d = np.broadcast_to(s_weft[:, None], (H, W))
    t_warp, axis_warp = _twisted_tangent(y_axis, x_axis, slope_warp, s_warp_2d, psi)
    t_weft, axis_weft = _twisted_tangent(x_axis, y_axis, slope_weft, s_weft_2d, psi)

    relief_warp = relief_weft = 0.0
    if ply_count > 1:
        z = np.array([0.0, 0.0, 1.0])
        for name, axis, s2d, along, across, across_vec, along_vec, length, diam in (
                ("warp", axis_warp, s_warp_2d, np.broadcast_to(y[:, None], (H, W)),
                 np.broadcast_to(dx[None, :], (H, W)), x_axis, y_axis, height_mm / n_weft,
                 np.broadcast_to(warp_width[j][None, :], (H, W))),
                ("weft", axis_weft, s_weft_2d, np.broadcast_to(x[None, :], (H, W)),
                 np.broadcast_to(dy[:, None], (H, W)), y_axis, x_axis, width_mm / n_warp,
                 np.broadcast_to(weft_width[i][:, None], (H, W)))):
            sc = np.clip(s2d, -1.0, 1.0)[..., None]
            n_y = sc * across_vec + np.sqrt(1.0 - sc * sc) * z
            n_y /= np.linalg.norm(n_y, axis=-1, keepdims=True)
            side = float(np.dot(np.cross(z, along_vec), across_vec))
            t_ply, q = _ply_tangent(axis, n_y, along, across, side, diam, length, ply_count, beta, psi)
            # Each ply is a small round bump: a groove between plies, 1/ply_count deep.
            relief = 0.5 * diam / ply_count * (np.sqrt(1.0 - q * q) - 1.0)
            if name == "warp":
                t_warp, relief_warp = t_ply, relief
            else:
                t_weft, relief_weft = t_ply, relief
        surf_warp = surf_warp + relief_warp
        surf_weft = surf_weft + relief_weft

    floor = -2.0 * max(amp_warp.max(), amp_weft.max())
    height_mm_map = np.where(warp_vis, surf_warp, np.where(weft_vis, surf_weft, floor))
    height = height_mm_map / width_mm             # tile-width units

    # Gap texels: the nearer yarn's axis (a valid unit vector; the gap map masks it).
    beyond_warp = np.abs(dx)[None, :] - 0.5 * warp_width[j][None, :]
    beyond_weft = np.abs(dy)[:, None] - 0.5 * weft_width[i][:, None]
    gap_axis = np.where((beyond_warp <= beyond_weft)[..., None], axis_warp, axis_weft)
    tangent = np.where(warp_vis[..., None], t_warp,
                       np.where(weft_vis[..., None], t_weft, gap_axis))

    yarn_id = np.where(warp_vis, j[None, :], np.where(weft_vis, n_warp + i[:, None], -1))
    albedo = np.where(warp_vis[..., None], warp_rgb[j][None, :, :],
                      np.where(weft_vis[..., None], weft_rgb[i][:, None, :], 0.0))

    meta = {
        "generator": "woven",
        "name": draft.name,
        "drawdown": dd.astype(np.int8).tolist(),
        "tile_size_mm": [width_mm, height_mm],
        "yarn_width": None if yarn_width is None else float(yarn_width),
        "gap_fraction": None if gap_fraction is None else float(gap_fraction),
        "yarn_height": yh,
        "profile_exponent": p_exp,
        "fibre_twist_deg": twist,
        "twist": "S" if twist > 0 else ("Z" if twist < 0 else "none"),
        "ply_count": int(ply_count),
        "ply_twist_deg": float(ply_twist_deg),
        "float_arch": arch,
        "warp_colors": np.asarray(warp_rgb).tolist(),
        "weft_colors": np.asarray(weft_rgb).tolist(),
    }
    return ClothMaps(tangent=tangent, normal=height_normal(height, 1.0 / W, (height_mm / width_mm) / H), height=height,
                     gap=yarn.astype(np.float32), yarn_id=yarn_id.astype(np.int32),
                     albedo=albedo, meta=meta)


__all__ = ["woven_maps", "srgb_to_linear"]
