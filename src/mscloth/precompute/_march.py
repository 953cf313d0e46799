"""Ray marching over a periodic, bilinearly interpolated height field (shared by the
visibility and parallax tables).

Heights and positions are in texel units: texel (r, c) has its centre at (x, y) = (c, r) and
height h[r, c]; between centres the surface is the bilinear interpolation, periodic in both
axes. A ray direction is given in texel units: (dx, dy) horizontal, rise dz (height units per
unit of horizontal texel travel is dz / |(dx, dy)|).

The march is done for every texel at once along one direction: at step k every texel's ray
sits at the same offset from its start, so the samples of step k are one shifted copy of the
height field (views into a 2x2-tiled array; no gathers). Steps: the dominant axis ("major")
advances by 1/m_div texel per step with m_div = ceil(sqrt(1 + slope^2) / max_step), so the
step along the ray's horizontal path is <= max_step texels; the fractional positions along the
major axis take only m_div values, precomputed once ("phases"), and each step needs a 1-D
linear interpolation along the minor axis only (exactly the bilinear surface). When few rays
remain undecided, the march continues on just those (gathers).
"""
from __future__ import annotations

import math

import numpy as np


class Sampler:
    """Samples of a periodic height field along one horizontal direction, for all texels."""

    def __init__(self, h: np.ndarray, dx: float, dy: float, max_step: float = 0.5):
        h = np.asarray(h, dtype=np.float32)
        self.transpose = abs(dy) > abs(dx)
        if self.transpose:
            h = np.ascontiguousarray(h.T)
            d_major, d_minor = dy, dx
        else:
            d_major, d_minor = dx, dy
        if d_major == 0.0:
            raise ValueError("Sampler: horizontal direction must be non-zero")
        self.h = h
        self.shape = h.shape
        Hm, Wm = h.shape
        self.sign = 1 if d_major > 0 else -1
        self.slope = float(d_minor) / abs(float(d_major))       # minor texels per major texel
        self.m_div = max(1, int(math.ceil(math.sqrt(1.0 + self.slope ** 2) / max_step - 1e-12)))
        self.step_len = math.sqrt(1.0 + self.slope ** 2) / self.m_div  # horizontal texels/step
        nxt = np.roll(h, -1, axis=1)
        # Phase p: the surface at major offset p/m_div (exact bilinear: linear along the row),
        # tiled 2x2 so that every shift is a view; ``diffs``: its difference to the next row.
        self._pstack = np.empty((self.m_div, 2 * Hm, 2 * Wm), dtype=np.float32)
        self._dstack = np.empty_like(self._pstack)
        for p in range(self.m_div):
            f = np.float32(p / self.m_div)
            ph = (h + f * (nxt - h)).astype(np.float32) if p else h
            self._pstack[p] = np.tile(ph, (2, 2))
            self._dstack[p] = np.tile(np.roll(ph, -1, axis=0) - ph, (2, 2))
        self.phases = list(self._pstack)
        self.diffs = list(self._dstack)
        self.flat = [ph.ravel() for ph in self.phases]
        self.flat_diff = [d.ravel() for d in self.diffs]
        self._buf = np.empty(self.shape, dtype=np.float32)

    # Offsets of step k: major = sign*k/m_div, minor = k*slope/m_div (texels).
    def _offsets(self, k: int):
        Hm, Wm = self.shape
        n = self.sign * k
        ix, phase = divmod(n, self.m_div)
        oy = k * self.slope / self.m_div
        iy = math.floor(oy)
        fy = np.float32(oy - iy)
        return phase, ix % Wm, iy % Hm, fy

    def major_minor(self, steps):
        """Offsets (major, minor) in texels after ``steps`` (float) steps."""
        return self.sign * steps / self.m_div, steps * self.slope / self.m_div

    def to_xy(self, major, minor):
        """(dx, dy) in texel units (columns, rows) of the original (untransposed) field."""
        return (minor, major) if self.transpose else (major, minor)

    def full(self, k: int) -> np.ndarray:
        """Heights at every texel's step-k sample, as a (working-orientation) array (reused)."""
        Hm, Wm = self.shape
        phase, ix, iy, fy = self._offsets(k)
        a = self.phases[phase][iy:iy + Hm, ix:ix + Wm]
        out = self._buf
        if fy == 0.0:
            out[...] = a
            return out
        np.multiply(self.diffs[phase][iy:iy + Hm, ix:ix + Wm], fy, out=out)
        out += a
        return out

    def base(self, flat_index: np.ndarray) -> np.ndarray:
        """Gather bases (into the tiled phase arrays) of texels with working-array flat index."""
        Hm, Wm = self.shape
        r, c = np.divmod(flat_index, Wm)
        return r * (2 * Wm) + c

    def gather(self, k: int, base: np.ndarray) -> np.ndarray:
        Hm, Wm = self.shape
        phase, ix, iy, fy = self._offsets(k)
        b0 = base + (iy * 2 * Wm + ix)
        a = self.flat[phase][b0]
        if fy == 0.0:
            return a
        d = self.flat_diff[phase][b0]
        d *= fy
        d += a
        return d

    def height_at(self, k: np.ndarray, flat_index: np.ndarray) -> np.ndarray:
        """Heights (float64) at per-texel step counts ``k`` (int array) from the texels with
        working-array flat index ``flat_index``."""
        Hm, Wm = self.shape
        k = np.asarray(k, dtype=np.int64)
        ix, phase = np.divmod(self.sign * k, self.m_div)
        oy = k * self.slope / self.m_div                  # as in _offsets
        iy = np.floor(oy)
        fy = oy - iy
        r, c = np.divmod(flat_index, Wm)
        idx = (phase * (4 * Hm * Wm) + ((r + iy.astype(np.int64)) % Hm) * (2 * Wm)
               + (c + ix) % Wm)
        return self._pstack.ravel()[idx] + fy * self._dstack.ravel()[idx]

    def to_working(self, arr: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(arr.T) if self.transpose else arr

    def from_working(self, arr: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(arr.T) if self.transpose else arr


# Switch from whole-array steps to gathers when fewer than this fraction of rays remain.
_COMPACT_FRACTION = 0.2
_CHECK_EVERY = 8
# Far-field blocks (see escape_mask): block length in major-axis texels.
_BLOCK_MIN, _BLOCK_MAX = 16, 48


def block_plan(slope: float, m_div: int, n_steps: int):
    """(Q, P, slope error) for the far field of escape_mask; None when the march is short.

    A block is Q major-axis texels (Q*m_div steps); the far field moves by the integer texel
    offset (Q, P), P = round(Q*slope), per block. Q in [16, 48] minimises the slope error
    |slope - P/Q|.
    """
    if n_steps <= 2 * _BLOCK_MIN * m_div:
        return None
    best = None
    for Q in range(_BLOCK_MIN, _BLOCK_MAX + 1):
        P = int(round(Q * slope))
        err = abs(Q * slope - P) / Q
        if best is None or err < best[2] - 1e-15:
            best = (Q, P, err)
    return best


def escape_mask(h: np.ndarray, direction_t, max_step: float = 0.5, eps: float = 1e-4,
                fast: bool = False) -> np.ndarray:
    """True where the ray from (c, r, h[r, c]) along ``direction_t`` does not hit the field.

    ``direction_t`` = (dx, dy, dz) in texel units with dz > 0 (upward). A hit is a sample where
    the surface lies more than ``eps`` above the ray; samples are taken until the ray is
    above max(h) (nothing can hit it later).

    Default: every texel's ray is marched sample by sample. ``fast=True``: only the first
    block of Q >= 16 major-axis texels (Q*m_div steps) is marched sample by sample; farther
    samples follow blocks joined at texel centres, i.e. the far field sees the direction
    rounded to the rational slope P/Q (|slope - P/Q| minimised over Q in [16, 48]: typically
    below 0.001 rad, at most ~0.01 rad), so that per-block maxima combine by doubling with
    integer shifts: M_2s(p) = max(M_s(p), M_s(p + s*(Q, P)) - s*rise_block). Cost: Q*m_div
    + log2 whole-field steps instead of up to (max(h) - min(h)) / rise. On the 512^2 plain
    weave (8x8 bins) it differs from the full march in 0.02 % of the entries, 3-8x faster.
    """
    h = np.asarray(h, dtype=np.float32)
    dx, dy, dz = (float(v) for v in direction_t)
    horiz = math.hypot(dx, dy)
    if horiz <= 1e-12 * max(1.0, abs(dz)):
        return np.ones(h.shape, dtype=bool)          # straight up: a height field cannot block it
    if dz <= 0.0:
        raise ValueError(f"escape_mask: direction must point upward (dz > 0), got dz = {dz}")
    s = Sampler(h, dx, dy, max_step)
    hw = s.h
    hmax = float(hw.max())
    rise = dz / horiz * s.step_len                   # height gained per step
    n_steps = int(math.ceil((hmax - float(hw.min())) / rise)) + 1
    thr = hw + np.float32(eps)
    plan = block_plan(s.slope, s.m_div, n_steps) if fast else None
    if plan is not None:
        Q, P, _ = plan
        n0 = Q * s.m_div
        M = np.full(s.shape, -np.inf, dtype=np.float32)
        for k in range(1, n0 + 1):
            v = s.full(k)
            v -= np.float32(k * rise)
            np.maximum(M, v, out=M)
        span = 1
        while span * n0 < n_steps:
            shifted = np.roll(M, (-span * P, -span * Q * s.sign), axis=(0, 1))
            shifted -= np.float32(span * n0 * rise)
            np.maximum(M, shifted, out=M)
            span *= 2
        return s.from_working(M <= thr)

    M = np.full(s.shape, -np.inf, dtype=np.float32)
    N = M.size
    active = None
    for k in range(1, n_steps + 1):
        r_k = np.float32(k * rise)
        if active is None:
            v = s.full(k)
            v -= r_k
            np.maximum(M, v, out=M)
            if k % _CHECK_EVERY == 0:
                und = (M <= thr) & (thr + np.float32((k + 1) * rise) < hmax)
                n = int(np.count_nonzero(und))
                if n == 0:
                    break
                if n < _COMPACT_FRACTION * N:
                    active = np.flatnonzero(und)
                    base = s.base(active)
                    Ma = M.ravel()[active]
                    tha = thr.ravel()[active]
        else:
            v = s.gather(k, base)
            v -= r_k
            np.maximum(Ma, v, out=Ma)
            if k % _CHECK_EVERY == 0:
                keep = (Ma <= tha) & (tha + np.float32((k + 1) * rise) < hmax)
                M.ravel()[active] = Ma
                if not keep.all():
                    active, base, Ma, tha = active[keep], base[keep], Ma[keep], tha[keep]
                if active.size == 0:
                    break
    if active is not None and active.size:
        M.ravel()[active] = Ma
    return s.from_working(M <= thr)


def first_hit_offsets(h: np.ndarray, direction_t, top: float | None = None,
                      max_step: float = 0.5):
    """Offsets (dx, dy) (texels, float32, each (H, W)) from texel (c, r) to where a ray that
    starts at (c, r, top) and travels along ``direction_t`` = (dx, dy, dz), dz < 0 (downward),
    first meets the height field (``top`` defaults to max(h)).

    Every sample is marched (no far-field shortcut). The crossing is then located between the
    last sample above and the first sample on or below the surface by linear interpolation
    of the ray's height above the surface.
    """
    h = np.asarray(h, dtype=np.float32)
    dx, dy, dz = (float(v) for v in direction_t)
    horiz = math.hypot(dx, dy)
    zero = np.zeros(h.shape, dtype=np.float32)
    if horiz <= 1e-12 * max(1.0, abs(dz)):
        return zero, zero.copy()                     # straight down: hits right below
    if dz >= 0.0:
        raise ValueError(f"first_hit_offsets: direction must point downward (dz < 0), got {dz}")
    s = Sampler(h, dx, dy, max_step)
    hw = s.h
    top = float(hw.max()) if top is None else float(top)
    fall = -dz / horiz * s.step_len                  # height lost per step
    n_steps = int(math.ceil((top - float(hw.min())) / fall)) + 2
    alive = hw < np.float32(top)
    # Steps survived above the surface; a ray's first hit is at step (survived + 1).
    survived = np.zeros(s.shape, dtype=np.int32)
    count8 = np.zeros(s.shape, dtype=np.uint8)       # cheap per-step counter, flushed often
    N = alive.size
    below = np.empty(s.shape, dtype=bool)
    late_hit = np.zeros(s.shape, dtype=np.int64)     # first-hit step of rays marched by gathers
    active = None
    for k in range(1, n_steps + 1):
        thr = np.float32(top - k * fall)
        if active is None:
            v = s.full(k)
            np.less(v, thr, out=below)
            alive &= below
            np.add(count8, alive.view(np.uint8), out=count8)
            if k % _CHECK_EVERY == 0:
                if k % 128 == 0:
                    survived += count8
                    count8[...] = 0
                n = int(np.count_nonzero(alive))
                if n == 0:
                    break
                if n < _COMPACT_FRACTION * N:
                    survived += count8
                    count8[...] = 0
                    active = np.flatnonzero(alive)
                    base = s.base(active)
        else:
            hit = s.gather(k, base) >= thr
            if hit.any():
                late_hit.ravel()[active[hit]] = k
                keep = ~hit
                active, base = active[keep], base[keep]
                if active.size == 0:
                    break
    survived += count8
    first = np.where(hw < np.float32(top), survived.astype(np.int64) + 1, 0)
    first = np.where(late_hit > 0, late_hit, first)
    first = np.minimum(first, n_steps)               # never hit: cannot happen for top >= min(h)
    # Secant between samples k1 - 1 (above) and k1 (on or below).
    idx = np.flatnonzero(first > 0)
    k1 = first.ravel()[idx]
    e1 = s.height_at(k1, idx) - (top - k1 * fall)
    e0 = s.height_at(k1 - 1, idx) - (top - (k1 - 1) * fall)
    den = e1 - e0
    with np.errstate(divide="ignore", invalid="ignore"):
        frac = np.where(den > 0, -e0 / den, 1.0)
    steps = np.zeros(N, dtype=np.float64)
    steps[idx] = (k1 - 1) + np.clip(frac, 0.0, 1.0)
    steps = steps.reshape(s.shape)
    major, minor = s.major_minor(steps)
    ox, oy = s.to_xy(major, minor)
    return (s.from_working(ox.astype(np.float32)), s.from_working(oy.astype(np.float32)))
