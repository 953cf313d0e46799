"""Sheen: a thin layer of fuzz fibres standing along the normal (our reading of
the paper, after Zeltner, Burley & Chiang 2022).

The fuzz is a SpongeCake layer of fibre-like SGGX flakes with tangent n = +z,
its own roughness ``alpha_s`` and optical thickness ``T_s``. It reflects by
single scattering, and what passes it unscattered both ways,

    T_sheen(i, o) = e^{-T_s |Lambda_s(i)|} e^{-T_s |Lambda_s(o)|},

reaches the cloth below (Eq. 1).

Sampling: :class:`TabulatedSheenSampler` draws wo in proportion to a table of
f_sheen |cos o| (JIT variants); :class:`FoldedSheenSampler` reflects on the fuzz's
visible normals (:func:`sample_sheen`). Both share one interface: ``sample(wi, u)`` and
``pdf(wi, wo)``. :class:`FuzzCosineSampler` draws the directions of diffuse light leaving
through the fuzz, |cos o| T_sheen(o).
"""
from __future__ import annotations

import weakref

import drjit as dr
import mitsuba as mi
import numpy as np

from . import spongecake
from ..jit_arrays import flat_array, gather, lane_values
from .alias_table import AliasTable


def _up(w):
    """The fuzz fibres' tangent: the macro normal (broadcasts to w's width)."""
    return mi.Vector3f(0.0, 0.0, 1.0)


def eval_sheen(wi, wo, alpha_s, thickness_s):
    """Sheen reflection f_sheen times |cos o| (no colour); zero for wo below."""
    return eval_sheen_transmittance(wi, wo, alpha_s, thickness_s)[0]


def eval_sheen_transmittance(wi, wo, alpha_s, thickness_s):
    """(:func:`eval_sheen`, T_sheen(i) T_sheen(o)): the second is what the evaluation's
    exponentials give anyway (:func:`spongecake.eval_specular_transmittance`), so the
    yarn lobes' light under the fuzz costs no exponential of its own."""
    value, reflect, both_ways = spongecake.eval_specular_transmittance(wi, wo, _up(wi), alpha_s, thickness_s)
    return dr.select(reflect, value, 0.0), both_ways


def sample_sheen(wi, alpha_s, sample):
    """(wo, pdf) from the fuzz's visible normals, folded to the upper hemisphere.

    At grazing incidence a large part of the visible-normal reflections points below the
    surface, where the sheen lobe is zero; mirroring them (z -> |z|) keeps every sample
    useful instead of returning a zero-weight sample (38% of them at 80 degrees)."""
    wo, _ = spongecake.sample_specular(wi, _up(wi), alpha_s, sample)
    wo = mi.Vector3f(wo.x, wo.y, dr.abs(wo.z))
    return wo, pdf_sheen(wi, wo, alpha_s)


def pdf_sheen(wi, wo, alpha_s):
    """Density of :func:`sample_sheen`: the visible-normal reflection density at wo plus
    at its mirror image below the surface (zero for wo below)."""
    below = mi.Vector3f(wo.x, wo.y, -wo.z)
    pdf = spongecake.pdf_specular(wi, wo, _up(wi), alpha_s) + spongecake.pdf_specular(wi, below, _up(wi), alpha_s)
    return dr.select(wo.z > 0.0, pdf, 0.0)


def sheen_transmittance(w, alpha_s, thickness_s):
    """e^{-T_s |Lambda_s(w)|}: one pass through the fuzz along w."""
    return spongecake.unscattered_transmittance(w, _up(w), alpha_s, thickness_s)


class FoldedSheenSampler:
    """:func:`sample_sheen` / :func:`pdf_sheen`: no table, any variant. The weight
    f/pdf varies with the attenuation of grazing outgoing directions and the fold:
    relative variance 0.05-0.19 from 88 to 20 degrees (alpha_s = 0.5, T_s = 0.3)."""

    def __init__(self, alpha_s):
        self.alpha_s = alpha_s

    def sample(self, wi, u):
        return sample_sheen(wi, self.alpha_s, u)

    def pdf(self, wi, wo):
        return pdf_sheen(wi, wo, self.alpha_s)


def _one_per_key(cache, key, make):
    """``cache[key]``, made by ``make()`` the first time (the per-fuzz tables: read-only, so
    BSDFs with the same fuzz share one)."""
    value = cache.get(key)
    if value is None:
        value = cache[key] = make()
    return value


class TabulatedSheenSampler:
    """Samples the sheen lobe in proportion to a table of f_sheen |cos o| (JIT variants).

    The fuzz is isotropic about the normal, so f_sheen |cos o| depends on cos(theta_i),
    cos(theta_o) and the azimuth between them, and only on its absolute value (the lobe is
    its own mirror image across the plane of wi and the normal). The table has one slice per
    band of incident angles (``n_mu`` bands, uniform in sqrt(cos theta_i)), each a
    piecewise-constant density on ``n_y`` x ``n_x`` cells of y = cos(theta_o) by
    x = |phi_o - phi_i| / pi (a cell stands for itself and its mirror image: d omega =
    2 pi dx dy over both), from the lobe at the cell centres for the band's centre. Rows are
    uniform in sqrt(y) and bands in sqrt(cos theta_i): finest at grazing angles, where the
    lobe changes fastest and the sheen dominates. ``sample`` picks a cell from the band's
    alias table (one read), a side of the mirror with what is left of the uniform, and a
    uniform point in the cell; ``pdf`` is one table read. The weight f/pdf varies only
    inside a cell and across a band: relative variance 0.0001-0.0011 from 20 to 89.5 degrees
    (alpha_s 0.5, T_s 0.3), against 0.014-0.19 for :class:`FoldedSheenSampler` (up to 34 at
    alpha_s 0.1, where the table gives 0.0002-0.007). 768 KiB and ~0.1 s to build at the
    default sizes; :meth:`shared` builds one table per sheen (BSDFs with the same fuzz read
    the same memory: these reads are cache misses more often than not).

    A cosine floor (``FLOOR`` of the band's mean) keeps every upper direction reachable
    for a very peaked lobe (small alpha_s). Sampling stays exact whatever the table holds
    (``pdf`` is the density of ``sample``), so a table left behind by changed sheen
    parameters only costs variance."""

    FLOOR = 0.01
    # Tables in use, by (variant, alpha_s, T_s): weak, so a table goes with its last BSDF.
    _shared = weakref.WeakValueDictionary()

    def __init__(self, values, n_mu: int, n_y: int, n_x: int):
        """``values``: (n_mu, n_y, n_x) non-negative cell values of f |cos o| (any scale per
        band); row j spans y in [(j / n_y)^2, ((j + 1) / n_y)^2], column i spans
        |phi_o - phi_i| in [i pi / n_x, (i + 1) pi / n_x]."""
        values = np.asarray(values, dtype=np.float64)
        if values.shape != (n_mu, n_y, n_x) or not np.all(np.isfinite(values)) or np.any(values < 0.0):
            raise ValueError(f"TabulatedSheenSampler: expected finite non-negative values of shape "
                             f"{(n_mu, n_y, n_x)}, got shape {values.shape}")
        self.n_mu, self.n_y, self.n_x = n_mu, n_y, n_x
        edges = (np.arange(n_y + 1) / n_y) ** 2
        # A cell and its mirror image: 2 (pi / n_x) in azimuth.
        solid_angle = (edges[1:] - edges[:-1])[None, :, None] * (2.0 * np.pi / n_x)
        mass = (values * solid_angle).reshape(n_mu, n_y * n_x)
        if np.any(mass.sum(axis=1) <= 0.0):
            raise ValueError("TabulatedSheenSampler: a band of the table is all zero")
        self.cells = AliasTable(mass)
        # The solid-angle pdf inside each cell: its realised probability over its size.
        self.density = self.cells.probabilities.reshape(n_mu, n_y, n_x) / solid_angle
        self._density = flat_array(self.density)

    @classmethod
    def build(cls, alpha_s, thickness_s, n_mu: int = 48, n_y: int = 64, n_x: int = 32):
        mu = ((np.arange(n_mu) + 0.5) / n_mu) ** 2
        y = ((np.arange(n_y) + 0.5) / n_y) ** 2
        x = (np.arange(n_x) + 0.5) / n_x
        M, Y, X = np.meshgrid(mu, y, x, indexing="ij")
        sin_i = np.sqrt(1.0 - M * M).ravel()
        sin_o = np.sqrt(1.0 - Y * Y)
        phi = np.pi * X
        wi = mi.Vector3f(*(lane_values(c) for c in (sin_i, np.zeros_like(sin_i), M)))
        wo = mi.Vector3f(*(lane_values(c) for c in (sin_o * np.cos(phi), sin_o * np.sin(phi), Y)))
        f_cos = np.asarray(eval_sheen(wi, wo, alpha_s, thickness_s), dtype=np.float64).reshape(M.shape)
        f_cos = np.where(np.isfinite(f_cos), np.maximum(f_cos, 0.0), 0.0)
        f_cos += cls.FLOOR * np.maximum(f_cos.mean(axis=(1, 2), keepdims=True), 1e-30) * Y
        return cls(f_cos, n_mu, n_y, n_x)

    @classmethod
    def shared(cls, alpha_s, thickness_s):
        """:meth:`build` at the default sizes, one table per (variant, alpha_s, T_s): the
        tables are read-only, so BSDFs with the same fuzz share one."""
        return _one_per_key(cls._shared, (mi.variant(), float(alpha_s), float(thickness_s)),
                            lambda: cls.build(alpha_s, thickness_s))

    def _band(self, wi):
        band = dr.floor(dr.sqrt(dr.maximum(wi.z, 0.0)) * self.n_mu)
        return mi.UInt32(dr.clip(band, 0, self.n_mu - 1))

    @staticmethod
    def _azimuth_of(wi):
        """(cos, sin) of wi's azimuth; the x axis for wi along the normal, where any
        azimuth will do as long as sample and pdf agree on it."""
        r2 = wi.x * wi.x + wi.y * wi.y
        has = r2 > 0.0
        inv_r = dr.rsqrt(dr.select(has, r2, 1.0))
        return dr.select(has, wi.x * inv_r, 1.0), dr.select(has, wi.y * inv_r, 0.0)

    def sample(self, wi, u):
        """(wo, pdf) for wi above the surface; wo is above too."""
        k = self._band(wi)
        cell, v = self.cells.sample(k, u.x)
        iy = cell // self.n_x
        ix = cell - iy * self.n_x
        # The side of the mirror from what is left of u.x (12 bits or more remain).
        mirror = v >= 0.5
        v = dr.select(mirror, 2.0 * v - 1.0, 2.0 * v)
        x = (mi.Float(ix) + v) * (0.5 / self.n_x)
        x = dr.select(mirror, -x, x)
        r0 = mi.Float(iy) / self.n_y
        r1 = r0 + 1.0 / self.n_y
        y = dr.lerp(r0 * r0, r1 * r1, u.y)  # uniform in y inside the cell
        c, s = self._azimuth_of(wi)  # rotated by 2 pi x (no atan2)
        sin_phi, cos_phi = dr.sincos(2.0 * dr.pi * x)
        sin_o = dr.safe_sqrt(1.0 - y * y)
        wo = mi.Vector3f(sin_o * (c * cos_phi - s * sin_phi), sin_o * (s * cos_phi + c * sin_phi), y)
        return wo, gather(self._density, k * (self.n_y * self.n_x) + cell)

    def pdf(self, wi, wo):
        """Solid-angle density of :meth:`sample` (zero for wo below)."""
        c, s = self._azimuth_of(wi)
        x = dr.abs(dr.atan2(c * wo.y - s * wo.x, c * wo.x + s * wo.y)) * dr.inv_pi
        ix = mi.UInt32(dr.clip(dr.floor(x * self.n_x), 0, self.n_x - 1))
        iy = mi.UInt32(dr.clip(dr.floor(dr.safe_sqrt(wo.z) * self.n_y), 0, self.n_y - 1))
        above = wo.z > 0.0
        density = gather(self._density, (self._band(wi) * self.n_y + iy) * self.n_x + ix, above)
        return dr.select(above, density, 0.0)


class FuzzCosineSampler:
    """Directions in proportion to |cos o| e^{-T_s |Lambda_s(o)|}: a diffuse lobe seen
    through the fuzz, which dims grazing directions (T_sheen(o) falls from 0.86 at the
    normal to 0.2 at 80 degrees for alpha_s 0.5, T_s 0.3).

    Cosine sampling leaves that factor in the weight (relative variance 0.075 for those
    parameters, 0.19 for T_s 0.6); here cos(theta_o) has a piecewise-constant density on
    ``cells`` regular cells (from the cell centres, an alias table to pick one: any
    variant) and the azimuth is uniform. ``sample(u)`` returns upper-hemisphere
    directions; ``pdf(w)`` is the density of w or of its mirror image below (callers pick
    the side)."""

    # Samplers in use, by (variant, alpha_s, T_s, cells): weak, so one goes with its last BSDF.
    _shared = weakref.WeakValueDictionary()

    @classmethod
    def shared(cls, alpha_s, thickness_s, cells: int = 256):
        """One sampler per fuzz, as :meth:`TabulatedSheenSampler.shared`: BSDFs with the same
        fuzz skip the kernel that measures its transmittance, and with it a wait on which
        Dr.Jit's thread pool may hand a loading thread another cloth's whole load
        (performance log L37)."""
        return _one_per_key(cls._shared, (mi.variant(), float(alpha_s), float(thickness_s), int(cells)),
                            lambda: cls(alpha_s, thickness_s, cells))

    def __init__(self, alpha_s, thickness_s, cells: int = 256):
        mu = (np.arange(cells) + 0.5) / cells
        sin = np.sqrt(1.0 - mu * mu)
        if dr.is_jit_v(mi.Float):
            w = mi.Vector3f(*(lane_values(c) for c in (sin, np.zeros_like(sin), mu)))
            t = np.asarray(sheen_transmittance(w, alpha_s, thickness_s))
        else:  # scalar variants: one direction at a time
            t = np.array([float(sheen_transmittance(mi.Vector3f(float(a), 0.0, float(b)), alpha_s, thickness_s))
                          for a, b in zip(sin, mu)])
        mass = mu * np.where(np.isfinite(t), t, 0.0)
        if not np.any(mass > 0.0):
            mass = mu  # a fuzz too thick to cross: any direction is as good
        self.n = cells
        self.cells = AliasTable(mass[None, :])
        # Solid-angle density: cell probability / (cell width * 2 pi).
        self._density = flat_array(self.cells.probabilities[0] * cells * (0.5 / np.pi))

    def sample(self, u):
        cell, v = self.cells.sample(0, u.x)
        cos_o = (mi.Float(cell) + v) / self.n
        sin_phi, cos_phi = dr.sincos(2.0 * dr.pi * u.y)
        sin_o = dr.safe_sqrt(1.0 - cos_o * cos_o)
        return mi.Vector3f(sin_o * cos_phi, sin_o * sin_phi, cos_o)

    def pdf(self, w):
        # A NaN direction reads cell 0 (scalar variants raise on UInt32(NaN)).
        cos_o = dr.select(dr.isnan(w.z), 0.0, dr.abs(w.z))
        cell = mi.UInt32(dr.clip(dr.floor(cos_o * self.n), 0, self.n - 1))
        return gather(self._density, cell)
