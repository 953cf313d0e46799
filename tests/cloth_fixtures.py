"""Shared helpers for the ``cloth`` BSDF tests: texels with known content, frames."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from mscloth.maps.builtin import resolve_pattern

N_TEXELS = 128  # the built-in plain weave's default tile resolution


def uv_of(row: int, col: int) -> list[float]:
    """UV of a texel centre of the built-in plain tile (uv_scale = 1)."""
    return [(col + 0.5) / N_TEXELS, (row + 0.5) / N_TEXELS]


def yarn_texels():
    """Texels on yarns with different fibre tangents (in plane, tilted up, on a flank)."""
    maps = resolve_pattern("plain")
    picks = [(32, 32), (32, 96), (16, 32), (32, 50)]
    for r, c in picks:
        assert maps.gap[r, c] == 1.0
    tangents = np.array([maps.tangent[r, c] for r, c in picks])
    # They really differ: no two share a direction.
    assert np.all(np.abs(tangents @ tangents.T - np.eye(len(picks))) < 0.995)
    return [uv_of(r, c) for r, c in picks]


def gap_texel():
    maps = resolve_pattern("plain")
    r, c = np.argwhere(maps.gap == 0.0)[0]
    return uv_of(int(r), int(c))


def direction(theta_deg: float, phi_deg: float, back: bool = False) -> list[float]:
    th, ph = np.radians(theta_deg), np.radians(phi_deg)
    z = np.cos(th) * (-1.0 if back else 1.0)
    return [float(np.sin(th) * np.cos(ph)), float(np.sin(th) * np.sin(ph)), float(z)]


def make_si(wi, uv, n: int):
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = wi
    si.uv = uv
    return si


def non_delta_context(component: int | None = None):
    ctx = mi.BSDFContext()
    ctx.type_mask = +mi.BSDFFlags.All & ~+mi.BSDFFlags.Delta
    if component is not None:
        ctx.component = component
    return ctx


def cloth_chi2_adapter(bsdf: dict, wi, uv, ctx):
    """Like ``mi.chi2.BSDFAdapter``, but a sample counts when its pdf is positive.

    Mitsuba's adapter drops samples whose *weight* is zero. Ours can be a valid
    sample with zero weight: at grazing exits the fuzz attenuation
    e^{-T_s |Lambda_s(o)|} underflows to 0 in float32 while the direction was
    drawn with a positive density. Dropping those would make the histogram
    disagree with the pdf although the sampler is right.
    """
    def make_si_for(n):
        return make_si(mi.Vector3f(wi), mi.Point2f(uv), n)

    def sample_func(sample, *args):
        plugin = mi.load_dict(bsdf)
        n = dr.width(sample)
        bs, _ = plugin.sample(ctx, make_si_for(n), sample[0], mi.Point2f(sample[1], sample[2]))
        return bs.wo, dr.select(bs.pdf > 0.0, 1.0, 0.0)

    def pdf_func(wo, *args):
        plugin = mi.load_dict(bsdf)
        return plugin.pdf(ctx, make_si_for(dr.width(wo)), wo)

    return sample_func, pdf_func


def footprint_chi2_adapter(bsdf: dict, wi, uv, ctx, half_texels: float):
    """:func:`cloth_chi2_adapter` with a square pixel footprint of ``half_texels`` texels
    (si.duv_dx / si.duv_dy set as the clothpath integrator does)."""
    d = 2.0 * half_texels / N_TEXELS

    def make(n):
        si = make_si(mi.Vector3f(wi), mi.Point2f(uv), n)
        si.duv_dx = mi.Vector2f(d, 0.0)
        si.duv_dy = mi.Vector2f(0.0, d)
        return si

    def sample_func(sample, *args):
        plugin = mi.load_dict(bsdf)
        bs, _ = plugin.sample(ctx, make(dr.width(sample)), sample[0], mi.Point2f(sample[1], sample[2]))
        return bs.wo, dr.select(bs.pdf > 0.0, 1.0, 0.0)

    def pdf_func(wo, *args):
        plugin = mi.load_dict(bsdf)
        return plugin.pdf(ctx, make(dr.width(wo)), wo)

    return sample_func, pdf_func


def hold_probe(monkeypatch, lanes: int, u: float = 0.4):
    """Hold the footprint estimator's probe number at ``u`` in every one of ``lanes`` lanes
    (the shading hash's third number), leaving each lane's residual texels and rounding
    its own: every lane then shades the same probe."""
    from mscloth.bsdf.footprint_estimator import FootprintEstimator

    hashed = FootprintEstimator.shading_hash

    def one_probe(self, si):
        xi, xi_round, _ = hashed(self, si)
        return xi, xi_round, mi.Float(np.full(lanes, u))

    monkeypatch.setattr(FootprintEstimator, "shading_hash", one_probe)
