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
import warnings
from numbers import Integral
from typing import Any

import numpy as np

from ..errors import ParameterError
from ..patterns.draft import Draft
from ..patterns.weaves import validate_drawdown
from .cloth_maps import ClothMaps
from .generator_support import (MapsWarning, check_memory, height_normal, real_in, srgb_to_linear,
                                tile_resolution, width_range)

MIN_TEXELS_PER_THREAD = 2
#: How far the gap fraction of the maps may be from the one asked for before a warning.
GAP_TOLERANCE = 0.05


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


def _pair(name: str, value: Any, lo: float, hi: float, lo_open: bool = False) -> tuple[float, float]:
    """A number in the interval for both yarns, or a (warp, weft) pair of them."""
    if isinstance(value, (tuple, list, np.ndarray)) and len(value) == 2:
        a, b = value
    elif isinstance(value, (tuple, list, np.ndarray)):
        raise ParameterError(f"{name} must be a number or a (warp, weft) pair, got {value!r}")
    else:
        a = b = value
    return (real_in(name, a, lo, hi, lo_open, False), real_in(name, b, lo, hi, lo_open, False))


def _as_draft(pattern: Any) -> Draft:
    return pattern if isinstance(pattern, Draft) else Draft(validate_drawdown(pattern))


def tile_shape(pattern: Any) -> tuple[float, tuple[int, int], int, tuple[str, str]]:
    """The arguments of :func:`~.generator_support.tile_resolution` after ``resolution`` for
    a draft's tile: its aspect (height / width), its (picks, ends), the fewest texels per
    thread and the threads' names."""
    draft = _as_draft(pattern)
    width_mm, height_mm = draft.size_mm
    return (height_mm / width_mm, (draft.n_weft, draft.n_warp), MIN_TEXELS_PER_THREAD,
            ("weft picks", "warp ends"))


def _thin_yarn_warning(W: int, H: int, width_mm: float, height_mm: float, warp_width, weft_width,
                       achieved: float, requested: float | None, shape) -> None:
    """Warn (MapsWarning) of maps that will not show the cloth asked for: a yarn narrower
    than one texel (sampled at texel centres it is hit or missed, so the cloth is mostly
    holes, or invisible) or a gap fraction more than GAP_TOLERANCE off the requested one,
    naming the resolution that resolves the yarn."""
    # Yarn widths in texels; a slubby yarn's mean width is its diameter.
    warp_texels = float(np.min(warp_width)) * W / width_mm
    weft_texels = float(np.min(weft_width)) * H / height_mm
    thin = min(warp_texels, weft_texels) < 1.0
    off = requested is not None and abs(achieved - requested) > GAP_TOLERANCE
    if not (thin or off):
        return
    family, texels = ("warp", warp_texels) if warp_texels <= weft_texels else ("weft", weft_texels)
    aspect, counts, least, _ = shape
    # Two texels across the narrowest yarn, and for a gap that is off, a texel grid fine
    # enough for the sampling error (at most a texel per thread edge, so ~1/resolution) to
    # fall to half the tolerance.
    wanted = 2.0 * W / min(warp_texels, weft_texels)
    if off:
        wanted = max(wanted, W * abs(achieved - requested) / (0.5 * GAP_TOLERANCE))
    low, high = width_range(aspect, counts, least)
    wanted = max(low, math.ceil(wanted))
    what = (f"the {family} yarn is {texels:.2g} texels wide" if thin else
            f"the narrowest yarn is {min(warp_texels, weft_texels):.2g} texels wide")
    gap = f"gap fraction {achieved:.3f}"
    if requested is not None and gap != f"gap fraction {requested:.3f}":
        gap += f" instead of the requested {requested:.3f}"
    fix = (f"{{res}} {wanted}{{along}} or more resolves it" if wanted <= high else
           f"no {{res}} up to {high} resolves it; a wider yarn does")
    warnings.warn(MapsWarning(f"woven maps of {W}x{H} texels: {what} ({gap}): {fix}"), stacklevel=3)


def _tile_resolution(resolution: Any, draft: Draft) -> tuple[int, int]:
    """An int is the width in texels (the height follows the tile's aspect); (H, W) is exact.
    ResolutionError also where the tile would not fit in memory."""
    shape = tile_shape(draft)
    pair = tile_resolution(resolution, *shape)
    check_memory(pair, *shape[:3])
    return pair


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


def slub_factors(count: int, period_mm: float, amplitude: float, pos_mm: np.ndarray, *,
                 length_mm: tuple[float, float] = (2.0, 8.0), spacing_mm: float = 12.0,
                 seed: Any = 0, bumps: bool = False):
    """Diameter / mean diameter of ``count`` slubby yarns at positions ``pos_mm`` along
    them, shape (count, len(pos_mm)): periodic with ``period_mm`` (the tile's length along
    the yarns), so a tile of them is seamless.

    Each yarn carries slubs, thick places a few mm long, at random along it: their number
    is Poisson with mean ``period_mm / spacing_mm``, their centres uniform, their lengths
    uniform in ``length_mm``; a slub's diameter rises along a raised cosine (C1) to
    ``1 + amplitude`` times the yarn's diameter between slubs (overlapping slubs take the
    larger). Each yarn is then scaled so that its mean diameter along the period is 1: the
    stated diameter is the mean one, thin places between slubs included. ``seed`` fixes the
    draw (any numpy seed). ``bumps``: also return the slub profile itself, 0 between slubs
    and 1 at a slub's peak, as a second array."""
    pos = np.asarray(pos_mm, dtype=np.float64)
    if amplitude == 0.0:
        return (np.ones((count, pos.size)), np.zeros((count, pos.size))) if bumps else np.ones((count, pos.size))
    rng = np.random.default_rng(seed)
    lo, hi = length_mm
    fine = (np.arange(2048) + 0.5) * (period_mm / 2048)
    out = np.empty((count, pos.size))
    profile = np.empty((count, pos.size))
    for k in range(count):
        n = rng.poisson(period_mm / spacing_mm)
        centres = rng.uniform(0.0, period_mm, n)
        lengths = rng.uniform(lo, hi, n)

        def slubs(p):
            b = np.zeros(p.shape)
            for c, length in zip(centres, lengths):
                half = 0.5 * min(length, period_mm)
                d = np.abs((p - c + 0.5 * period_mm) % period_mm - 0.5 * period_mm)
                b = np.maximum(b, np.where(d < half, 0.5 + 0.5 * np.cos(np.pi * d / half), 0.0))
            return b

        profile[k] = slubs(pos)
        out[k] = (1.0 + amplitude * profile[k]) / np.mean(1.0 + amplitude * slubs(fine))
    return (out, profile) if bumps else out


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


def draft_slub_factors(draft, slub: Any, along_u: np.ndarray, along_v: np.ndarray, *,
                       length_mm: tuple[float, float], spacing_mm: float, seed: int, bumps: bool = False):
    """(warp, weft) :func:`slub_factors` of a draft's yarns as the woven maps draw them: its
    warp ends at ``along_v`` (mm down the tile) and its weft picks at ``along_u`` (mm across),
    ``slub`` one amplitude for both or a (warp, weft) pair, each family seeded from ``seed``
    on its own."""
    slub_warp, slub_weft = _pair("slub", slub, 0.0, 4.0)
    width_mm, height_mm = draft.size_mm
    kw = dict(length_mm=length_mm, spacing_mm=spacing_mm, bumps=bumps)
    return (slub_factors(draft.n_warp, height_mm, slub_warp, along_v, seed=[seed, 0], **kw),
            slub_factors(draft.n_weft, width_mm, slub_weft, along_u, seed=[seed, 1], **kw))


def _yarns(centres, spacing, diam, amp, level, cross_centres, period_across: float,
           period_along: float, across: np.ndarray, along: np.ndarray, factors: np.ndarray,
           profile: np.ndarray, slubby: bool, bulge) -> dict:
    """The visible yarn of one family (warp ends as columns: ``across`` = x, ``along`` = y;
    the weft's is the transpose) at every texel, (len(along), len(across)) arrays: its
    thread index, offset from its centre (mm), local width, s = offset / half-width (|s| <= 1
    on the yarn), centreline slope, surface height and slub profile (0 between slubs, 1 at
    a slub's peak). ``level``: centreline / A at each (crossing, thread); ``factors``,
    ``profile``: (threads, len(along)) slub diameter factors and profile.

    Even yarns fill at most their own band (width = min(diameter, spacing)). Slubby yarns
    may spread over their neighbours' bands, up to their local diameter (at most to the
    neighbours' centres): each texel then
    takes the highest of its own thread and the two beside it, so a slub shows wider where
    it lies over its neighbours and they narrow beside it."""
    n = len(centres)
    j, dx = _threads(centres, spacing, across)                          # (W,)
    k0, k1, w, dw = _crossings(cross_centres, period_along, along)      # (H,)
    best = None
    for shift in ((0, -1, 1) if slubby and n > 1 else (0,)):
        jj = (j + shift) % n
        off = across - centres[jj]
        off = off - period_across * np.round(off / period_across)       # periodic, (W,)
        off2 = np.broadcast_to(off[None, :], (len(along), len(across)))
        f = factors[jj].T                                                # (H, W)
        cap = 2.0 * spacing[jj] if slubby else spacing[jj]   # slubs: at most to the neighbours' centres
        width = np.minimum(diam[jj][None, :] * f, cap[None, :])
        s_ = off2 / (0.5 * width)
        a = amp[jj][None, :]
        h0 = a * level[k0[:, None], jj[None, :]]
        h1 = a * level[k1[:, None], jj[None, :]]
        centre = h0 + (h1 - h0) * w[:, None]
        slope = (h1 - h0) * dw[:, None]
        surf = centre + bulge(a * f, s_)
        on = np.abs(s_) <= 1.0
        cand = {"thread": np.broadcast_to(jj[None, :], s_.shape), "offset": off2, "width": width,
                "s": s_, "slope": slope, "surface": np.where(on, surf, -np.inf), "raw": surf,
                "slub": profile[jj].T}
        if best is None:
            best = cand
        else:
            win = cand["surface"] > best["surface"]
            best = {k: np.where(win, cand[k], best[k]) for k in best}
    on_any = np.isfinite(best["surface"])
    best["surface"] = np.where(on_any, best["surface"], best.pop("raw"))
    best.pop("raw", None)
    return best


def woven_maps(pattern: Any, resolution: int | tuple[int, int] = (128, 128), *,
               yarn_width: float | None = None, gap_fraction: float | None = None,
               yarn_height: float = 0.35, profile_exponent: float = 2.0,
               fibre_twist_deg: float = 30.0, ply_count: int = 1, ply_twist_deg: float = 30.0,
               warp_colors: Any = None, weft_colors: Any = None, float_arch: float = 0.0,
               slub: Any = 0.0, slub_length_mm: tuple[float, float] = (2.0, 8.0),
               slub_spacing_mm: float = 12.0, slub_seed: int = 0, slub_tone: float = 1.0) -> ClothMaps:
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
        slub: slubby yarns, >= 0, or a (warp, weft) pair: each yarn thickens at slubs
            along it to 1 + slub times its diameter between them (:func:`slub_factors`,
            mean diameter kept), with its width (at most its spacing), its cross-section's
            height and so the gap, height and normal maps; 0: even yarns.
        slub_length_mm: (shortest, longest) slub, mm, 0 < shortest <= longest.
        slub_spacing_mm: mean distance between slubs along a yarn, mm, > 0.
        slub_seed: an int fixing where the slubs are.
        slub_tone: the yarn's albedo at a slub's peak / between slubs, in [0.5, 2] (clipped
            to albedo 1): raised slubs catch more light than the model's height alone gives.

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
        warp_diam, weft_diam = w * draft.warp_spacing, w * draft.weft_spacing
    else:
        warp_diam, weft_diam = np.asarray(draft.warp_thickness), np.asarray(draft.weft_thickness)
    warp_width = np.minimum(warp_diam, draft.warp_spacing)
    weft_width = np.minimum(weft_diam, draft.weft_spacing)
    slub_warp, slub_weft = _pair("slub", slub, 0.0, 4.0)
    slub_lo, slub_hi = _pair("slub_length_mm", slub_length_mm, 0.0, math.inf, lo_open=True)
    if slub_lo > slub_hi:
        raise ParameterError(f"slub_length_mm must be (shortest, longest), got {slub_length_mm!r}")
    slub_gap = real_in("slub_spacing_mm", slub_spacing_mm, 0.0, math.inf, True, True)
    tone = real_in("slub_tone", slub_tone, 0.5, 2.0, False, False)
    if isinstance(slub_seed, bool) or not isinstance(slub_seed, Integral):
        raise ParameterError(f"slub_seed must be an integer, got {slub_seed!r}")
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

    # Slubs: each yarn's diameter / its mean along it, (H, W) for the visible thread of
    # each row band (warp: along v) and column band (weft: along u). A slub widens the
    # yarn up to its spacing and raises its cross-section; the centreline keeps the mean
    # yarn's crimp.
    # (ends, H) and (picks, W)
    (f_warp, b_warp), (f_weft, b_weft) = draft_slub_factors(
        draft, (slub_warp, slub_weft), x, y, length_mm=(slub_lo, slub_hi), spacing_mm=slub_gap, seed=slub_seed,
        bumps=True)
    # Warp end j: column band, centreline interpolated along v between weft crossings.
    warp = _yarns(warp_centre, draft.warp_spacing, warp_diam, amp_warp, warp_level,
                  weft_centre, width_mm, height_mm, x, y, f_warp, b_warp, slub_warp > 0.0, bulge)
    # Weft pick i: row band; the weft is over exactly where the warp is under. The same
    # construction with u and v swapped.
    weft = {k: v.T for k, v in _yarns(weft_centre, draft.weft_spacing, weft_diam, amp_weft,
                                      weft_level.T, warp_centre, height_mm, width_mm, y, x, f_weft,
                                      b_weft, slub_weft > 0.0, bulge).items()}
    j, dx, warp_w2d, s_warp = warp["thread"], warp["offset"], warp["width"], warp["s"]
    slope_warp, surf_warp = warp["slope"], warp["surface"]
    i, dy, weft_w2d, s_weft = weft["thread"], weft["offset"], weft["width"], weft["s"]
    slope_weft, surf_weft = weft["slope"], weft["surface"]

    in_warp = np.abs(s_warp) <= 1.0
    in_weft = np.abs(s_weft) <= 1.0
    warp_vis = in_warp & (~in_weft | (surf_warp >= surf_weft))
    weft_vis = in_weft & ~warp_vis
    yarn = warp_vis | weft_vis

    x_axis = np.array([1.0, 0.0, 0.0])
    y_axis = np.array([0.0, 1.0, 0.0])
    s_warp_2d, s_weft_2d = s_warp, s_weft
    t_warp, axis_warp = _twisted_tangent(y_axis, x_axis, slope_warp, s_warp_2d, psi)
    t_weft, axis_weft = _twisted_tangent(x_axis, y_axis, slope_weft, s_weft_2d, psi)

    relief_warp = relief_weft = 0.0
    if ply_count > 1:
        z = np.array([0.0, 0.0, 1.0])
        for name, axis, s2d, along, across, across_vec, along_vec, length, diam in (
                ("warp", axis_warp, s_warp_2d, np.broadcast_to(y[:, None], (H, W)),
                 dx, x_axis, y_axis, height_mm / n_weft, warp_w2d),
                ("weft", axis_weft, s_weft_2d, np.broadcast_to(x[None, :], (H, W)),
                 dy, y_axis, x_axis, width_mm / n_warp, weft_w2d)):
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

    floor = -2.0 * max(amp_warp.max(), amp_weft.max())  # below the thin places' undersides
    height_mm_map = np.where(warp_vis, surf_warp, np.where(weft_vis, surf_weft, floor))
    height = height_mm_map / width_mm             # tile-width units

    # Gap texels: the nearer yarn's axis (a valid unit vector; the gap map masks it).
    beyond_warp = np.abs(dx) - 0.5 * warp_w2d
    beyond_weft = np.abs(dy) - 0.5 * weft_w2d
    gap_axis = np.where((beyond_warp <= beyond_weft)[..., None], axis_warp, axis_weft)
    tangent = np.where(warp_vis[..., None], t_warp,
                       np.where(weft_vis[..., None], t_weft, gap_axis))

    yarn_id = np.where(warp_vis, j, np.where(weft_vis, n_warp + i, -1))
    # Slubs stand proud of the cloth and catch more light than the thin places beside
    # them, an occlusion the maps' height does not give the fibre-level BSDF: slub_tone.
    tone_warp = 1.0 + (tone - 1.0) * warp["slub"]
    tone_weft = 1.0 + (tone - 1.0) * weft["slub"]
    albedo = np.where(warp_vis[..., None], np.minimum(1.0, warp_rgb[j] * tone_warp[..., None]),
                      np.where(weft_vis[..., None], np.minimum(1.0, weft_rgb[i] * tone_weft[..., None]), 0.0))

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
        "slub": [slub_warp, slub_weft],
        "slub_length_mm": [slub_lo, slub_hi],
        "slub_spacing_mm": slub_gap,
        "slub_seed": int(slub_seed),
        "slub_tone": tone,
        "warp_colors": np.asarray(warp_rgb).tolist(),
        "weft_colors": np.asarray(weft_rgb).tolist(),
    }
    _thin_yarn_warning(W, H, width_mm, height_mm, warp_width, weft_width, 1.0 - float(yarn.mean()),
                       None if gap_fraction is None else float(gap_fraction), tile_shape(draft))
    # What the draft's reader had to guess or found odd (a WIF file's warnings), so that
    # maps.json keeps it: "<file>: <message>", as the reader warned.
    draft_warnings = draft.meta.get("warnings") if isinstance(draft.meta, dict) else None
    if draft_warnings:
        source = draft.meta.get("file")
        meta["warnings"] = [f"{source}: {w}" if source else str(w) for w in draft_warnings]
    return ClothMaps(tangent=tangent, normal=height_normal(height, 1.0 / W, (height_mm / width_mm) / H), height=height,
                     gap=yarn.astype(np.float32), yarn_id=yarn_id.astype(np.int32),
                     albedo=albedo, meta=meta)


__all__ = ["slub_factors", "woven_maps", "srgb_to_linear"]
