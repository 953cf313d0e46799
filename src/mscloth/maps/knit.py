"""Cloth maps of a weft-knitted fabric from a stitch grid: loop geometry, fibre twist, holes.

Geometry (our reading of docs/design.md §5; a sinusoidal loop model in the spirit of the classic
Peirce / Leaf loop models, not a quote of the paper):

* Units: the wale spacing is 1 ("wale units"); the course spacing is ``loop_aspect`` = a.
  The tile holds one repeat of ``pattern.stitches`` (n_courses, n_wales): it is n_wales wide
  and n_courses * a tall, so it is generally not square; ``meta['tile_size_mm']`` gives its
  physical (width, height) and ``meta['tile_aspect']`` height / width. Stitch (i, j) is the
  cell u in [j, j+1) / n_wales, v in [i, i+1) / n_courses. Heights are in tile widths.
* Each course is one yarn whose centreline, in the course's own frame (x along +u, y along
  +v from the course centre line), is the periodic curve

      x(T) = (T + A sin 2T) / 2pi,   y(T) = h cos T,

  one stitch per 2pi of T. T = 0 is a sinker arc (between wales, at +v, the bottom of the
  loop in the preview image, where +v points down), T = pi the loop head (at -v, reaching
  into the course above), and around T = pi/2 and 3pi/2 the two legs. With A > 1/2 the curve
  narrows into a neck just above the sinkers and widens below the head, so the two legs of a
  loop form the "V" of a knit stitch. h = loop_height * a / 2 (loops reach into the
  neighbouring courses, which is how they intermesh), and A is set so that the legs are
  tilted by ``leg_tilt_deg`` from the wale (v) direction at their midpoints. Going from the
  neck toward the head (toward -v) the left leg moves toward -u and the right leg toward +u.
* Depth: z = d * profile(T) with d = yarn_height / 2 (wale units). Sigma = +1 for knit,
  -1 for purl. Stitch (i, j) says how loop i passes through the head of loop i+1 (the
  course below in +v): knit -> the legs and neck of loop i lie in front (+d) and loop i+1's
  head and course i's sinkers lie behind (-d); purl is the mirror image (head and sinkers in
  front: the purl bump). Hence on loop i of stitch j: legs at +sigma(i,j) d, sinkers at
  -sigma d, and the head at -sigma(i-1, j) d; between stitches of different kinds (rib,
  seed, garter) the profile blends smoothly (C1, cosine/sine blends over quarter periods).
* Rib relief: a rib's purl wales lie behind its knit wales (the fabric draws together,
  the knit wales stand proud). Each wale j is offset in depth by
  o_j = rib_depth * yarn_width * (m_j - mean m) / 2, m_j the mean of sigma down the wale;
  the offset is the wale's own over the loop's head and legs and blends to the next wale's
  across each sinker along a half sine (C1), like the profile.
* Rasterising: for every texel and every course whose band (|y| <= h + r) contains it, the
  nearest point of that course's centreline is found (initial guess from a precomputed table
  over one stitch period, then Newton steps on the analytic curve); distance dist in the
  (u, v) plane. The texel is on that yarn if dist < r = yarn_width / 2, with surface height
  z(T) + sqrt(r^2 - dist^2) (circular cross-section); the visible yarn is the highest one.
  Holes (gap = 0) are texels on no yarn; they get height -(d + r), under the lowest yarn.
* Fibre tangent: the yarn axis a = normalize(x'(T), y'(T), z'(T)) rotated about the
  cross-section normal n_y (centreline -> surface point, made orthogonal to a) by the twist
  psi: t = cos(psi) a + sin(psi) (n_y x a), the construction of woven.py (psi > 0 = S twist).
  In holes the tangent is the untwisted axis of the nearest course's centreline.
* Normal: from the periodic height gradient (central differences, physical texel sizes).
* yarn_id = course index (one yarn per course in weft knitting); albedo = the stitch's
  colour (course colours win over wale colours), sRGB converted to linear.

Everything is a periodic function of (u, v) sampled at texel centres: the tile is seamless.

Approximations: yarns are round, rigid tubes that may interpenetrate (at the default
yarn_width neighbouring wales' legs overlap in projection; the higher surface wins), with no
flattening where they press together; the fabric does not curl or fold (garter courses are
not compressed, and a rib's purl wales recede by ``rib_depth`` but its knit wales do not
close over them); the nearest-point search can settle
on a slightly farther local minimum on a few texels where two branches are almost equally
near a texel at the yarn's edge (inside tight arcs), which shifts the tangent there.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..errors import ParameterError, PatternError
from ..patterns.knit import KnitPattern, validate_stitches
from .cloth_maps import ClothMaps
from .generator_support import check_memory, height_normal, real_in, srgb_to_linear, tile_resolution

MIN_TEXELS_PER_STITCH = 4
DEFAULT_LOOP_ASPECT = 0.8  # knit_maps' loop_aspect: course spacing / wale spacing
_TABLE_X = 128          # initial-guess table: nodes per stitch period along u
_TABLE_SAMPLES = 192    # curve samples per stitch period when building the table
_NEWTON_STEPS = 3
_TWO_PI = 2.0 * math.pi
# Largest A with T + A sin 2T >= 0 on [0, pi] (minimum of -T / sin 2T there): the left leg
# never crosses x = 0, i.e. a loop's legs stay inside its own wale's [0, 1] strip.
_AMP_MAX = 2.3016


# ---------------------------------------------------------------- argument checks
def _as_pattern(pattern: Any) -> KnitPattern:
    if isinstance(pattern, KnitPattern):
        return pattern
    if isinstance(pattern, str):
        raise PatternError(f"knit_maps: expected a KnitPattern or a stitch array, got the "
                           f"string {pattern!r} (use mscloth.patterns.knit.{pattern}() or "
                           f"similar)")
    return KnitPattern(validate_stitches(pattern))


def tile_shape(pattern: Any, loop_aspect: float = DEFAULT_LOOP_ASPECT
               ) -> tuple[float, tuple[int, int], int, tuple[str, str]]:
    """The arguments of :func:`~.generator_support.tile_resolution` after ``resolution`` for
    a knit's tile: its aspect (height / width), its (courses, wales), the fewest texels per
    stitch and the stitches' names."""
    nc, nw = _as_pattern(pattern).stitches.shape
    return nc * loop_aspect / nw, (nc, nw), MIN_TEXELS_PER_STITCH, ("courses", "wales")


# ---------------------------------------------------------------- the course curve
class _Curve:
    """x(T) = (T + A sin 2T) / 2pi, y(T) = h cos T (wale units), and its derivatives."""

    def __init__(self, amp: float, half_height: float):
        self.A = amp
        self.h = half_height

    def xy(self, T):
        return (T + self.A * np.sin(2.0 * T)) / _TWO_PI, self.h * np.cos(T)

    def nearest(self, T, qx, qy, steps: int = _NEWTON_STEPS):
        """Newton steps on |P(T) - Q|^2 / 2 from T; returns (T, dx, dy) with d = P - Q."""
        A, h = self.A, self.h
        inv = 1.0 / _TWO_PI
        for _ in range(steps):
            s, c = np.sin(T), np.cos(T)
            s2, c2 = 2.0 * s * c, 1.0 - 2.0 * s * s
            dx = (T + A * s2) * inv - qx
            dy = h * c - qy
            px = (1.0 + 2.0 * A * c2) * inv
            py = -h * s
            ppx = -4.0 * A * s2 * inv
            ppy = -h * c
            g = dx * px + dy * py
            speed2 = px * px + py * py
            hess = speed2 + dx * ppx + dy * ppy
            # Newton where the objective is convex, a gradient step (Gauss-Newton) elsewhere.
            denom = np.where(hess > 0.05 * speed2, hess, speed2)
            T = T - np.clip(g / denom, -0.25, 0.25)
        x, y = self.xy(T)
        return T, x - qx, y - qy

    def derivative(self, T):
        return (1.0 + 2.0 * self.A * np.cos(2.0 * T)) / _TWO_PI, -self.h * np.sin(T)


def _guess_table(curve: _Curve, ext: float) -> tuple[np.ndarray, float, int]:
    """Nearest-sample T over fx in [0, 1) x y in [-ext, ext]; returns (table, dy, ny).

    Row iy is y = -ext + iy * dy; column ix is the cell fx in [ix, ix + 1) / nx.
    """
    nx = _TABLE_X
    ny = max(2, int(math.ceil(2.0 * ext * nx)) + 1)
    step_y = 2.0 * ext / (ny - 1)
    # Nodes at cell centres: with nx even, the loop's mirror lines x = 0 and x = 1/2 (where
    # the left and right legs, or two sinker halves, are equally near) are cell borders, so
    # a texel's cell node is always on the texel's side of them.
    qx = (np.arange(nx) + 0.5) / nx
    qy = -ext + np.arange(ny) * step_y
    # Samples over T in [-pi, 3pi): the stitch period under fx plus half a period each side
    # (the curve stays within x in [k, k + 1] for T in [2 pi k, 2 pi (k + 1)]).
    ts = -math.pi + np.arange(2 * _TABLE_SAMPLES) * (_TWO_PI / _TABLE_SAMPLES)
    sx, sy = curve.xy(ts)
    table = np.empty((ny, nx))
    for r0 in range(0, ny, 64):
        yy = qy[r0:r0 + 64]
        d2 = ((sx[None, None, :] - qx[None, :, None]) ** 2
              + (sy[None, None, :] - yy[:, None, None]) ** 2)
        table[r0:r0 + 64] = ts[np.argmin(d2, axis=-1)]
    return table, step_y, ny


def _depth(tl, sig, sig_above, sig_left, sig_right, d, off=0.0, off_left=0.0, off_right=0.0):
    """Centreline depth z and dz/dT at local parameter tl in [0, 2pi) (module docstring);
    ``off*``: the wale offsets (rib relief) of this stitch's wale and its neighbours'."""
    head = (tl >= 0.5 * math.pi) & (tl < 1.5 * math.pi)
    right = tl >= 1.5 * math.pi
    # Head/leg quarter periods [pi/2, 3pi/2): legs at +sig d, head at -sig_above d.
    S = 0.5 * (sig + sig_above)
    D = 0.5 * (sig - sig_above)
    z_head = d * (-S * np.cos(2.0 * tl) + D)
    dz_head = d * (2.0 * S * np.sin(2.0 * tl))
    # Sinker quarter periods around T = 0 (between stitch j-1 and j) and T = 2pi (j, j+1).
    s = np.where(right, tl - _TWO_PI, tl)
    sl = np.where(right, sig, sig_left)
    sr = np.where(right, sig_right, sig)
    z_sink = d * (-0.5 * (sl + sr) * np.cos(2.0 * s) + 0.5 * (sr - sl) * np.sin(s))
    dz_sink = d * ((sl + sr) * np.sin(2.0 * s) + 0.5 * (sr - sl) * np.cos(s))
    # Wale offset: the wale's own over the head and legs, blended across each sinker along
    # a half sine (C1) to the neighbouring wale's.
    ol = np.where(right, off, off_left)
    orr = np.where(right, off_right, off)
    o_sink = 0.5 * (ol + orr) + 0.5 * (orr - ol) * np.sin(s)
    do_sink = 0.5 * (orr - ol) * np.cos(s)
    z = np.where(head, z_head + off, z_sink + o_sink)
    return z, np.where(head, dz_head, dz_sink + do_sink)


# ---------------------------------------------------------------- the generator
def knit_maps(pattern: Any, resolution: int | tuple[int, int] = 256, *,
              yarn_width: float = 0.45, loop_aspect: float = DEFAULT_LOOP_ASPECT, loop_height: float = 1.5,
              leg_tilt_deg: float = 25.0, yarn_height: float | None = None,
              fibre_twist_deg: float = 30.0, wale_spacing_mm: float = 1.0,
              rib_depth: float = 1.0) -> ClothMaps:
    """Build the maps of one seamless tile of a weft-knitted fabric (geometry: module doc).

    Args:
        pattern: a :class:`~mscloth.patterns.knit.KnitPattern`, or a stitch array
            (n_courses, n_wales) of 1 = knit / 0 = purl.
        resolution: texels along u (the height follows the tile's physical aspect, so texels
            are square), or an exact (H, W); at least 4 texels per stitch each way.
        yarn_width: yarn diameter / wale spacing, in (0, 1].
        loop_aspect: course spacing / wale spacing, in [0.3, 3].
        loop_height: centreline loop height (sinker to head) / course spacing, in [1, 3]:
            how far each loop reaches into its neighbouring courses.
        leg_tilt_deg: angle of the stitch legs to the wale direction at their midpoints, in
            [0, 45] degrees, and small enough that the legs stay inside their wale (about
            43 degrees at the default loop shape, less for taller loops; ParameterError
            says the limit).
        yarn_height: peak-to-peak centreline depth (front layer to back layer) / wale
            spacing, in (0, 2]; default ``yarn_width`` (layers one yarn diameter apart).
        fibre_twist_deg: fibre angle to the yarn axis in degrees, [-90, 90]; > 0 is an S
            twist, < 0 a Z twist (as in woven maps).
        wale_spacing_mm: physical wale spacing, > 0, only for ``meta['tile_size_mm']``.
        rib_depth: how far the purl wales of a rib lie behind its knit wales / yarn width,
            in [0, 4]: each wale is offset in depth by rib_depth * yarn_width * (its mean
            stitch kind, +1 knit to -1 purl, minus the tile's mean) / 2, so a k x p rib's
            knit wales stand rib_depth yarn widths proud of its purl wales, and patterns
            whose wales all mix knit and purl alike (jersey, garter, seed) are unchanged.

    Returns ClothMaps; yarn ids are course indices (-1 in holes); albedo is the linear colour
    of the visible stitch; meta holds the parameters, the stitches, ``tile_aspect`` and
    ``tile_size_mm``.
    """
    pat = _as_pattern(pattern)
    stitches = pat.stitches
    nc, nw = stitches.shape
    w = real_in("yarn_width", yarn_width, 0.0, 1.0, lo_open=True, hi_open=False)
    a = real_in("loop_aspect", loop_aspect, 0.3, 3.0, False, False)
    lh = real_in("loop_height", loop_height, 1.0, 3.0, False, False)
    tilt = real_in("leg_tilt_deg", leg_tilt_deg, 0.0, 45.0, False, False)
    yh = w if yarn_height is None else real_in("yarn_height", yarn_height, 0.0, 2.0,
                                                  lo_open=True, hi_open=False)
    twist = real_in("fibre_twist_deg", fibre_twist_deg, -90.0, 90.0, False, False)
    mm = real_in("wale_spacing_mm", wale_spacing_mm, 0.0, math.inf, True, True)
    rib = real_in("rib_depth", rib_depth, 0.0, 4.0, False, False)
    shape = tile_shape(pat, a)
    aspect = shape[0]
    H, W = tile_resolution(resolution, *shape)
    check_memory((H, W), *shape[:3])
    psi = math.radians(twist)

    r = 0.5 * w
    d = 0.5 * yh
    h = 0.5 * lh * a
    amp = 0.5 * (1.0 + _TWO_PI * h * math.tan(math.radians(tilt)))
    if amp > _AMP_MAX:
        most = math.degrees(math.atan((2.0 * _AMP_MAX - 1.0) / (_TWO_PI * h)))
        raise ParameterError(f"leg_tilt_deg {tilt:g} is too large for loop_aspect {a:g} and "
                             f"loop_height {lh:g}: the legs would cross into the neighbouring "
                             f"wales (at most {most:.1f} degrees here)")
    curve = _Curve(amp, h)
    ext = h + r                                  # half-height of a course's yarn band
    table, step_y, ny = _guess_table(curve, ext)

    sig = 2.0 * stitches.astype(np.float64) - 1.0  # +1 knit, -1 purl
    wale_kind = sig.mean(axis=0)                    # +1 a knit wale, -1 a purl wale
    wale_off = 0.5 * rib * w * (wale_kind - wale_kind.mean())
    rgb = srgb_to_linear(pat.stitch_colors())      # (nc, nw, 3)

    # Texel centres in wale units; fx/jc: position within / index of the wale column.
    X = (np.arange(W) + 0.5) * (nw / W)
    jc = np.floor(X)
    fx = X - jc
    jc = jc.astype(np.int64)
    ix = np.minimum(np.floor(fx * _TABLE_X).astype(np.int64), _TABLE_X - 1)
    Yall = (np.arange(H) + 0.5) * (nc * a / H)
    kb = np.floor(Yall / a).astype(np.int64)       # course whose cell holds the row

    best_h = np.full((H, W), -np.inf)
    best_T = np.zeros((H, W))                       # local T (relative to wale column jc)
    best_dx = np.zeros((H, W))
    best_dy = np.zeros((H, W))
    best_dz = np.zeros((H, W))
    best_k = np.zeros((H, W), np.int64)             # course (unwrapped)
    best_j = np.zeros((H, W), np.int64)             # stitch within the course (wrapped)
    near_d2 = np.full((H, W), np.inf)               # for hole tangents: nearest centreline
    near_T = np.zeros((H, W))
    near_dz = np.zeros((H, W))

    m = int(math.ceil(ext / a + 0.5)) + 1
    for di in range(-m, m + 1):
        k = kb + di
        Y = Yall - (k + 0.5) * a                    # offset from course k's centre line
        rows = np.nonzero(np.abs(Y) <= ext)[0]
        if rows.size == 0:
            continue
        Yr, kr = Y[rows], k[rows]
        iy = np.clip(np.rint((Yr + ext) / step_y).astype(np.int64), 0, ny - 1)
        T0 = table[iy[:, None], ix[None, :]]
        qx = np.broadcast_to(fx[None, :], T0.shape)
        qy = np.broadcast_to(Yr[:, None], T0.shape)
        T, dx, dy = curve.nearest(T0, qx, qy)
        d2 = dx * dx + dy * dy
        s = np.floor(T / _TWO_PI)
        tl = T - _TWO_PI * s
        j = (jc[None, :] + s.astype(np.int64)) % nw
        kk = (kr % nc)[:, None]
        ka = ((kr - 1) % nc)[:, None]
        z, dz = _depth(tl, sig[kk, j], sig[ka, j], sig[kk, (j - 1) % nw],
                       sig[kk, (j + 1) % nw], d, wale_off[j], wale_off[(j - 1) % nw],
                       wale_off[(j + 1) % nw])
        surf = np.where(d2 < r * r, z + np.sqrt(np.maximum(r * r - d2, 0.0)), -np.inf)

        cur = best_h[rows]
        win = surf > cur
        best_h[rows] = np.where(win, surf, cur)
        for arr, val in ((best_T, T), (best_dx, dx), (best_dy, dy), (best_dz, dz),
                         (best_j, j), (best_k, np.broadcast_to(kr[:, None], T.shape))):
            arr[rows] = np.where(win, val, arr[rows])
        cur = near_d2[rows]
        near = d2 < cur
        near_d2[rows] = np.where(near, d2, cur)
        near_T[rows] = np.where(near, T, near_T[rows])
        near_dz[rows] = np.where(near, dz, near_dz[rows])

    yarn = np.isfinite(best_h)
    floor = -(d + r) + float(wale_off.min())
    height = np.where(yarn, best_h, floor) / nw    # tile widths

    # Fibre tangent of the visible yarn; untwisted axis of the nearest course in holes.
    T = np.where(yarn, best_T, near_T)
    px, py = curve.derivative(T)
    axis = np.stack([px, py, np.where(yarn, best_dz, near_dz)], axis=-1)
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    rise = np.sqrt(np.maximum(r * r - (best_dx ** 2 + best_dy ** 2), 0.0))
    n_y = np.stack([-best_dx, -best_dy, rise], axis=-1)   # centreline -> surface point
    n_y -= np.sum(n_y * axis, axis=-1, keepdims=True) * axis
    n_len = np.linalg.norm(n_y, axis=-1, keepdims=True)
    n_y = np.where(n_len > 1e-12, n_y / np.maximum(n_len, 1e-300), 0.0)
    t = math.cos(psi) * axis + math.sin(psi) * np.cross(n_y, axis)
    t /= np.linalg.norm(t, axis=-1, keepdims=True)
    tangent = np.where(yarn[..., None], t, axis)

    course = np.where(yarn, best_k % nc, -1)
    albedo = np.where(yarn[..., None], rgb[np.maximum(course, 0), best_j], 0.0)

    meta = {
        "generator": "knit",
        "name": pat.name,
        "stitches": stitches.astype(int).tolist(),
        "tile_aspect": aspect,
        "tile_size_mm": [nw * mm, nc * a * mm],
        "yarn_width": w,
        "loop_aspect": a,
        "loop_height": lh,
        "leg_tilt_deg": tilt,
        "yarn_height": yh,
        "fibre_twist_deg": twist,
        "twist": "S" if twist > 0 else ("Z" if twist < 0 else "none"),
        "wale_spacing_mm": mm,
        "rib_depth": rib,
        "stitch_colors": rgb.tolist(),
    }
    return ClothMaps(tangent=tangent, normal=height_normal(height, 1.0 / W, aspect / H),
                     height=height, gap=yarn.astype(np.float32),
                     yarn_id=course.astype(np.int32), albedo=albedo, meta=meta)


__all__ = ["knit_maps", "srgb_to_linear"]
