"""The ``cloth`` BSDF's lobe mixture: which lobe a sample takes (probabilities from cheap
albedo proxies, calibrated by :mod:`.lobe_calibration`), how each lobe is sampled exactly,
and the mixture's density. Shared by the fibre-level BSDF (one texel's tangent) and the
footprint estimator (its residual texels' tangents, the footprint's averages).

Variant-agnostic: ``mi`` and ``dr`` of the variant active when called. Directions are in
the mirrored frame (the viewer above)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import drjit as dr
import mitsuba as mi

from ..scattering import sggx, sheen, spongecake
from ..lanes import logical_not
from .lobes import DIFFUSE_REFLECTION, DIFFUSE_TRANSMISSION, GAP, SHEEN, SPECULAR_REFLECTION, SPECULAR_TRANSMISSION
from .shading_state import LobeAlbedos, max_channel


def lobe_proxies(k: LobeAlbedos, wi, yarn, ts, scattered, enabled) -> list:
    """Cheap unnormalised albedo estimates of the six lobes (the gap's is exact), for yarn
    coverage ``yarn``, albedos ``k`` (yarn colour included), fuzz transmittance ``ts``
    towards the viewer and ``scattered``, the share of light the specular slab scatters."""
    zero = dr.zeros(mi.Float, dr.width(wi))
    w = [zero] * 6
    if enabled[SHEEN]:
        w[SHEEN] = max_channel(k.sheen_color) * (1.0 - ts)
    spec = zero
    if enabled[SPECULAR_REFLECTION]:
        spec = max_channel(k.specular_albedo)
    if enabled[SPECULAR_TRANSMISSION]:
        spec = dr.maximum(spec, max_channel(k.specular_transmittance))
    w[SPECULAR_REFLECTION] = ts * yarn * spec * scattered
    if enabled[DIFFUSE_REFLECTION]:
        w[DIFFUSE_REFLECTION] = ts * yarn * max_channel(k.diffuse_albedo)
    if enabled[DIFFUSE_TRANSMISSION]:
        w[DIFFUSE_TRANSMISSION] = ts * yarn * max_channel(k.diffuse_transmittance)
    if enabled[GAP]:
        w[GAP] = ts * ts * (1.0 - yarn)
    return w


def lobe_weights(k: LobeAlbedos, wi, yarn, ts, scattered, enabled, calibration) -> list:
    """Normalised lobe probabilities: the :func:`lobe_proxies` times ``calibration``'s
    ratios (:class:`.lobe_calibration.LobeCalibration`; None: the raw proxies). The
    specular reflection slot stands for both specular lobes (one sampled flake lobe)."""
    w = lobe_proxies(k, wi, yarn, ts, scattered, enabled)
    if calibration is not None:
        w = calibration.scale(w, wi.z)
    total = w[0] + w[1] + w[2] + w[3] + w[4] + w[5]
    inv = dr.select(total > 0.0, dr.rcp(total), 0.0)
    return [wk * inv for wk in w]


def _mirrored(w):
    """``w`` mirrored through the surface plane."""
    return mi.Vector3f(w.x, w.y, -w.z)


@dataclass
class SpecularHalfVectors:
    """The half vectors of the specular density at (wi, wo): of wo, and of wo mirrored
    through the surface (the folded samples), where each density is defined
    (:func:`.spongecake.specular_half_vector`)."""

    direct: Any
    valid: Any
    folded: Any
    valid_folded: Any

    @staticmethod
    def of(wi, wo) -> SpecularHalfVectors:
        h, valid = spongecake.specular_half_vector(wi, wo)
        h_folded, valid_folded = spongecake.specular_half_vector(wi, _mirrored(wo))
        return SpecularHalfVectors(h, valid, h_folded, valid_folded)


@dataclass
class LobeSamplers:
    """How the sheen and the diffuse lobes are sampled for a fuzz (sheen roughness and
    thickness); the specular lobe is sampled from the SGGX flakes' visible normals."""

    sheen: Any
    diffuse: Any

    #: Whether flake samples below the surface are folded up (:meth:`fold_share`); off,
    #: for experiments and tests, the specular lobe samples its flakes as they fall.
    FOLD_FLAKES = True

    @classmethod
    def fold_share(cls, k: LobeAlbedos, enabled):
        """The probability that a flake reflection which leaves below the surface is
        mirrored above it. The specular lobes are one flake lobe scaled by
        ``specular_albedo`` above and ``specular_transmittance`` below; a fibre's flakes
        reflect into a cone that the surface plane cuts in two nearly equal halves, so
        unfolded, about half the specular samples land below even where transmission is
        weak (satin: 0.05 against 0.8). Folding a share f = (R - T) / (R + T) of them up
        makes the density ratio below/above (1 - f) / (1 + f) = T / R, the lobes' own."""
        if not cls.FOLD_FLAKES:
            return 0.0
        r = max_channel(k.specular_albedo) if enabled[SPECULAR_REFLECTION] else 0.0
        t = max_channel(k.specular_transmittance) if enabled[SPECULAR_TRANSMISSION] else 0.0
        total = r + t
        return dr.select(total > 0.0, dr.maximum(r - t, 0.0) / dr.select(total > 0.0, total, 1.0), 0.0)

    @staticmethod
    def for_fuzz(sheen_roughness, alpha_s: float, thickness_s: float) -> LobeSamplers:
        """The samplers of the fuzz (``alpha_s``, ``thickness_s`` as Python floats;
        ``sheen_roughness`` the live parameter). Tables carry no gradient and need none:
        sampling steers the estimate, never its expectation."""
        # The sheen lobe sampled from a table of itself (JIT variants; scalar variants,
        # for unit tests, reflect on the fuzz's visible normals).
        sheen_sampler = sheen.FoldedSheenSampler(sheen_roughness)
        with dr.suspend_grad():
            # Diffuse lobes leave through the fuzz: sampled with its transmittance.
            diffuse = sheen.FuzzCosineSampler.shared(alpha_s, thickness_s)
            if dr.is_jit_v(mi.Float) and thickness_s > 0.0:
                sheen_sampler = sheen.TabulatedSheenSampler.shared(alpha_s, thickness_s)
        return LobeSamplers(sheen=sheen_sampler, diffuse=diffuse)

    @staticmethod
    def specular_pdf(roughness, wi, wo, tangent, fold):
        """Density of sampling the specular lobe on ``tangent``'s flakes, a share ``fold``
        of its samples below the surface mirrored above; validity not masked."""
        hv = SpecularHalfVectors.of(wi, wo)
        return LobeSamplers.specular_pdf_from(hv, wo, fold, sggx.ndf(hv.direct, tangent, roughness),
                                              sggx.ndf(hv.folded, tangent, roughness),
                                              sggx.projected_area(wi, tangent, roughness))

    @staticmethod
    def specular_pdf_from(hv: SpecularHalfVectors, wo, fold, d_direct, d_folded, sigma_i):
        """:meth:`specular_pdf` from a tangent's D at ``hv``'s two half vectors and its
        sigma(wi): the form for many tangents at one pair of directions, which computes
        the half vectors once and shares D(h) and sigma(wi) with the evaluation."""
        # One division for both densities (their denominator, 4 sigma(wi), is the same).
        inv = spongecake.pdf_specular_from(1.0, sigma_i, hv.valid | hv.valid_folded)
        direct = dr.select(hv.valid, d_direct * inv, 0.0)
        folded = dr.select(hv.valid_folded, d_folded * inv, 0.0)
        return dr.select(wo.z > 0.0, direct + fold * folded, (1.0 - fold) * direct)

    def pdf(self, roughness, wi, wo, probs, tangents, enabled, fold, specular_mean=None):
        """Density of picking a lobe by ``probs`` and sampling it, the specular lobe from
        one of ``tangents`` chosen uniformly (or, if given, its density ``specular_mean``
        already averaged over them: :meth:`specular_pdf`), a share ``fold``
        (:meth:`fold_share`) of its samples below the surface mirrored above; validity not
        masked."""
        up = wo.z > 0.0
        pdf = mi.Float(0.0)
        if enabled[SHEEN]:
            pdf += probs[SHEEN] * self.sheen.pdf(wi, wo)
        if enabled[SPECULAR_REFLECTION] or enabled[SPECULAR_TRANSMISSION]:
            side_ok = (up & enabled[SPECULAR_REFLECTION]) | (logical_not(up) & enabled[SPECULAR_TRANSMISSION])
            if specular_mean is None:
                spec = mi.Float(0.0)
                for t in tangents:
                    spec += self.specular_pdf(roughness, wi, wo, t, fold)
                specular_mean = spec * (1.0 / len(tangents))
            pdf += probs[SPECULAR_REFLECTION] * dr.select(side_ok, specular_mean, 0.0)
        if enabled[DIFFUSE_REFLECTION] or enabled[DIFFUSE_TRANSMISSION]:
            diffuse = self.diffuse.pdf(wo)
            if enabled[DIFFUSE_REFLECTION]:
                pdf += probs[DIFFUSE_REFLECTION] * dr.select(up, diffuse, 0.0)
            if enabled[DIFFUSE_TRANSMISSION]:
                pdf += probs[DIFFUSE_TRANSMISSION] * dr.select(up, 0.0, diffuse)
        return pdf

    def sample(self, roughness, wi, tangent, probs, enabled, sample1, sample2, active, fold, strata: int = 1):
        """One lobe picked by ``sample1`` against ``probs`` and sampled with ``sample2``
        (the specular lobe on ``tangent``'s flakes, folded up with probability ``fold``
        where it leaves below): (wo, ok, component, gap_ok). ``strata``: into how many
        equal parts of the specular slot the caller already cut ``sample1`` (the fold
        decision takes the position within one)."""
        c_sheen = probs[SHEEN]
        c_spec = c_sheen + probs[SPECULAR_REFLECTION]
        c_dr = c_spec + probs[DIFFUSE_REFLECTION]
        c_dt = c_dr + probs[DIFFUSE_TRANSMISSION]
        c_all = c_dt + probs[GAP]
        pick_sheen = sample1 < c_sheen
        pick_spec = logical_not(pick_sheen) & (sample1 < c_spec)
        pick_dr = logical_not(pick_sheen) & logical_not(pick_spec) & (sample1 < c_dr)
        pick_dt = logical_not(pick_sheen) & logical_not(pick_spec) & logical_not(pick_dr) & (sample1 < c_dt)
        pick_gap = (logical_not(pick_sheen) & logical_not(pick_spec) & logical_not(pick_dr) & logical_not(pick_dt)
                    & (sample1 < c_all) & (probs[GAP] > 0.0))

        wo_spec, _ = spongecake.sample_specular(wi, tangent, roughness, sample2)
        u_spec = (sample1 - c_sheen) * strata / dr.select(probs[SPECULAR_REFLECTION] > 0.0,
                                                           probs[SPECULAR_REFLECTION], 1.0)
        do_fold = (wo_spec.z < 0.0) & (u_spec - dr.floor(u_spec) < fold)
        wo_spec.z = dr.select(do_fold, -wo_spec.z, wo_spec.z)
        wo_sheen = wo_spec
        if enabled[SHEEN]:
            wo_sheen, _ = self.sheen.sample(wi, sample2)
        wo_diffuse = self.diffuse.sample(sample2)
        wo_diffuse.z = dr.select(pick_dt, -wo_diffuse.z, wo_diffuse.z)
        wo = dr.select(pick_sheen, wo_sheen, dr.select(pick_spec, wo_spec, wo_diffuse))

        lands_up = wo.z > 0.0
        ok = active & (wi.z > spongecake.COS_EPSILON) & (pick_sheen | pick_spec | pick_dr | pick_dt)
        ok &= logical_not(pick_sheen) | lands_up
        ok &= logical_not(pick_spec) | dr.select(lands_up, enabled[SPECULAR_REFLECTION],
                                                 enabled[SPECULAR_TRANSMISSION])
        component = dr.select(pick_sheen, SHEEN,
                    dr.select(pick_spec, dr.select(lands_up, SPECULAR_REFLECTION, SPECULAR_TRANSMISSION),
                    dr.select(pick_dr, DIFFUSE_REFLECTION, DIFFUSE_TRANSMISSION)))
        gap_ok = active & pick_gap & (wi.z > spongecake.COS_EPSILON)
        return wo, ok, mi.UInt32(component), gap_ok
