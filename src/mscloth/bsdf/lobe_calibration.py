"""Lobe-selection calibration of the ``cloth`` BSDF's sampler.

The sampler picks one lobe per sample with a probability proportional to a cheap estimate
of that lobe's albedo (a *proxy*: the yarn coverage times the lobe's colour times the fuzz
transmittance, ...). The proxies are consistent with each other only up to factors the
proxies leave out: the light the fuzz absorbs on the way out, the shadowing of the height
field, the energy a specular flake sends out of the slab, the share of a colour's mean in
its maximum. The delta gap's proxy is its exact value, so it was sampled up to 6x too
rarely against the other lobes, and a few gap samples with large weights dominated the
noise under an environment.

At construction we measure, per cosine of the incident angle, the ratio of each lobe's
actual albedo (the mean weight of lobe-only fibre-level samples over random texels and
azimuths) to the mean of its proxy, and the sampler multiplies each proxy by its ratio.
Any positive factor keeps sampling unbiased (``pdf`` uses the same probabilities); good
ones cut the variance of the sample weight at 40-75 degrees 3-4x for footprints and
1.1-1.4x at the fibre level (docs/performance-log.md L6).

Albedo shares are the best choice only where every lobe samples its own shape exactly.
Where one does not (the flake lobe's transmitted half; the footprint mixture, which samples
the specular lobe from four texels' tangents and adds a defensive cosine), its samples come
back with spread weights, and where lobes overlap, one lobe's samples carry another's
light. For the footprint mixture a second pass samples whole footprints with the albedo
ratios and scales each lobe's probability by the root mean square of its samples' weights
(:func:`measure_share_factors`): the choice that minimises the second moment of the weight
when a lobe's weights scale inversely with its probability, which holds exactly for the
delta gap and closely for the others. At the fibre level that assumption fails (a texel is
all gap or all yarn, so the gap's probability is 0 or nearly 1 whatever its factor), and
the pass gained only 2-3% there; the fibre-level sampler keeps the albedo ratios.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..jit_arrays import flat_array, gather_block, lane_values, opaque
from .lobes import (DIFFUSE_REFLECTION, DIFFUSE_TRANSMISSION, GAP, SHEEN, SPECULAR_REFLECTION,
                    SPECULAR_TRANSMISSION, enabled_lobes)

#: Lobes with a measured ratio: (proxy slot, components whose albedos it covers). The
#: specular proxy stands for the flake lobe, which reflects and transmits. The gap's proxy
#: is its albedo (ratio 1); it takes part in the second pass.
CALIBRATED = ((SHEEN, (SHEEN,)), (SPECULAR_REFLECTION, (SPECULAR_REFLECTION, SPECULAR_TRANSMISSION)),
              (DIFFUSE_REFLECTION, (DIFFUSE_REFLECTION,)), (DIFFUSE_TRANSMISSION, (DIFFUSE_TRANSMISSION,)),
              (GAP, (GAP,)))
#: No lobe drops below this share of its proxy, so that each stays reachable wherever the
#: measurement saw (nearly) nothing of it.
MIN_RATIO = 0.02
#: The second stage moves a lobe's probability by at most this factor either way, so that
#: every lobe stays well reachable (its weights' second moments come from a few hundred
#: samples per cosine, heavy-tailed for some lobes).
MAX_SHARE_FACTOR = 4.0
#: A lobe needs this many of the second pass's samples at a cosine to be rescaled there.
MIN_SHARE_SAMPLES = 64


def _lanes(nodes: int, lanes: int, seed: int):
    """Fibre-level shading points (zero footprint; uv_scale 1) at cos(theta_i) =
    (j + 1/2) / nodes, ``lanes`` random texels and azimuths per node, and their two sample
    arguments."""
    rng = np.random.default_rng(seed)
    mu = np.repeat((np.arange(nodes) + 0.5) / nodes, lanes)
    n = mu.size
    phi = rng.random(n) * 2.0 * np.pi
    sin_t = np.sqrt(1.0 - mu * mu)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    # Aligned inputs: every pass on fresh samples traces (and compiles) the same kernel.
    si.wi = mi.Vector3f(*(lane_values(c) for c in (sin_t * np.cos(phi), sin_t * np.sin(phi), mu)))
    si.uv = mi.Point2f(lane_values(rng.random(n)), lane_values(rng.random(n)))
    return si, lane_values(rng.random(n)), mi.Point2f(lane_values(rng.random(n)), lane_values(rng.random(n)))


#: Footprint width (texels) at which the second pass samples the footprint mixture.
SHARE_FOOTPRINT_TEXELS = 64.0
#: Passes of the second stage, each on fresh samples with the factors so far: the factors
#: move towards the fixed point where every lobe's weights have the same root mean square
#: (weight variance of the plane's twill, 20 / 60 degrees: albedo ratios 0.126 / 0.128,
#: after one pass 0.096 / 0.095, three 0.066 / 0.066, six 0.043 / 0.048, twelve 0.037 /
#: 0.039). Every pass traces the same kernel (aligned inputs, :func:`_lanes`), so passes
#: after the first cost ~25 ms each.
SHARE_PASSES = 12
#: Each pass multiplies the factors by its measured ones to this power (1: the plain fixed
#: point iteration; more steps further along the same direction).
SHARE_RELAXATION = 1.25
#: Samples per node of the share passes: the last SHARE_FINAL_PASSES passes take
#: SHARE_LANES, the ones before SHARE_EARLY_LANES: the passes after them correct their
#: factors, so they need less precision. 8 passes at 1024 and 4 at 4096, stepping 1.25:
#: half the samples of 12 passes at 4096 for the same weight variance, within the seeds'
#: spread (bench/calibration_passes.py; performance log L34).
SHARE_LANES = 4096
SHARE_EARLY_LANES = 1024
SHARE_FINAL_PASSES = 4


def calibrate(bsdf, proxies_at, estimator=None, texel_uv=None, nodes: int = 16, lanes: int = 1024, seed: int = 0):
    """(fibre-level calibration, footprint calibration or None): the albedo ratios
    (:func:`measure_ratios`), and for a multi-scale BSDF (its footprint ``estimator``,
    ``texel_uv``: the (u, v) size of one texel) the same times the share factors of the
    footprint mixture measured with them in place (:func:`measure_share_factors`).
    Leaves ``estimator.calibration`` as it found it."""
    point = LobeCalibration(measure_ratios(bsdf, proxies_at, nodes, lanes, seed))
    if texel_uv is None or estimator is None:
        return point, None
    before = estimator.calibration
    footprint_uv = (SHARE_FOOTPRINT_TEXELS * texel_uv[0], SHARE_FOOTPRINT_TEXELS * texel_uv[1])
    calibration = LobeCalibration(point.albedo_ratios)
    try:
        for k in range(SHARE_PASSES):
            estimator.calibration = calibration
            share_lanes = SHARE_LANES if k >= SHARE_PASSES - SHARE_FINAL_PASSES else SHARE_EARLY_LANES
            factors = calibration.factors * measure_share_factors(bsdf, footprint_uv, nodes, share_lanes,
                                                                  seed + 1 + k) ** SHARE_RELAXATION
            calibration = LobeCalibration(point.albedo_ratios,
                                          np.clip(factors, 1.0 / MAX_SHARE_FACTOR, MAX_SHARE_FACTOR))
    finally:
        estimator.calibration = before
    return point, calibration


def measure_ratios(bsdf, proxies_at, nodes: int = 16, lanes: int = 1024, seed: int = 0) -> np.ndarray:
    """(len(CALIBRATED), nodes) ratios of mean albedo to mean proxy at cos(theta_i) =
    (j + 1/2) / nodes, over ``lanes`` random texels and azimuths per node (a fixed seed:
    the same BSDF always gets the same table).

    ``proxies_at(si)``: the BSDF's unnormalised proxies (six per-lane values) at the
    fibre-level texels of ``si``."""
    si, s1, s2 = _lanes(nodes, lanes, seed)
    albedo = {}
    for component in sorted({c for _, comps in CALIBRATED for c in comps}):
        ctx = mi.BSDFContext()
        ctx.component = component
        _, weight = bsdf.sample(ctx, si, s1, s2)
        albedo[component] = (weight[0] + weight[1] + weight[2]) * (1.0 / 3.0)
    proxies = proxies_at(si)
    wanted = list(albedo.values()) + [proxies[slot] for slot, _ in CALIBRATED]
    dr.eval(*wanted)

    def per_node(x):
        return np.asarray(x, dtype=np.float64).reshape(nodes, lanes).mean(axis=1)

    ratios = np.ones((len(CALIBRATED), nodes))
    for row, (slot, comps) in enumerate(CALIBRATED):
        a = sum(per_node(albedo[c]) for c in comps)
        p = per_node(proxies[slot])
        seen = p > 0.0
        ratios[row, seen] = a[seen] / p[seen]
    top = ratios.max(axis=1, keepdims=True)
    return np.maximum(ratios, MIN_RATIO * np.maximum(top, 1e-6))


def measure_share_factors(bsdf, footprint_uv, nodes: int = 16, lanes: int = 4096, seed: int = 1) -> np.ndarray:
    """(len(CALIBRATED), nodes) factors on the lobes' probabilities, from samples of the
    whole mixture as ``bsdf`` samples it now, on footprints ``footprint_uv`` = (width,
    height) in uv at random places.

    Where lobe g is picked with probability p_g and its samples' weights have second moment
    E[w^2 | g], the weight's second moment is sum_g p_g E[w^2 | g]. If g's weights scale as
    1/p_g (exact for the delta gap; close for lobes that overlap little), the choice
    p'_g ~ sqrt(p_g^2 E[w^2 | g]) minimises it: a factor sqrt(E[w^2 | g]) on p_g, the root
    mean square of g's weights. Normalised to a p-weighted mean of 1 per node; lobes with
    fewer than MIN_SHARE_SAMPLES samples at a node keep factor 1 there."""
    si, s1, s2 = _lanes(nodes, lanes, seed)
    # Opaque: BSDFs whose tiles differ in size (footprint_uv with them) trace one kernel.
    si.duv_dx = mi.Vector2f(opaque(mi.Float, footprint_uv[0]), 0.0)
    si.duv_dy = mi.Vector2f(0.0, opaque(mi.Float, footprint_uv[1]))
    # Inputs evaluated first, so the pass's kernel holds the sampling alone.
    dr.eval(si, s1, s2)
    bs, weight = bsdf.shading.sample_footprint(enabled_lobes(mi.BSDFContext()), si, s1, s2)
    dr.eval(bs.sampled_component, bs.pdf, weight)  # one kernel: the pdf read below too
    w = np.asarray(weight, dtype=np.float64).mean(axis=0)
    comp = np.asarray(bs.sampled_component)
    ok = np.isfinite(w) & (np.asarray(bs.pdf) > 0.0)
    # Each sample's (node, calibrated row), summed at once: counts and sums of w^2.
    rows = len(CALIBRATED)
    row_of = np.full(int(comp.max(initial=0)) + 1, -1)
    for row, (_, comps) in enumerate(CALIBRATED):
        row_of[[c for c in comps if c < row_of.size]] = row
    row = row_of[comp]
    keep = ok & (row >= 0)
    cell = (np.arange(comp.size) // lanes) * rows + row
    picked = np.bincount(cell[keep], minlength=nodes * rows).reshape(nodes, rows).T
    w2 = np.bincount(cell[keep], weights=w[keep] ** 2, minlength=nodes * rows).reshape(nodes, rows).T
    seen = picked >= MIN_SHARE_SAMPLES
    rms = np.sqrt(w2 / np.maximum(picked, 1))
    factors = np.where(seen & (rms > 0.0), rms, 1.0)
    # Normalised per node to a picked-weighted mean of 1 over the seen lobes; unseen lobes
    # keep the seen ones' mean, so only the seen ones move.
    count = np.sum(np.where(seen, picked, 0), axis=0)
    mean = np.sum(np.where(seen, picked * factors, 0.0), axis=0) / np.maximum(count, 1)
    factors = np.where(seen, factors / np.where(count > 0, mean, 1.0), 1.0)
    return np.clip(factors, 1.0 / MAX_SHARE_FACTOR, MAX_SHARE_FACTOR)


class LobeCalibration:
    """The measured ratios (times the share factors, if any) in Dr.Jit memory, interpolated
    linearly in cos(theta_i). ``albedo_ratios``: the first pass alone."""

    def __init__(self, ratios: np.ndarray, factors: np.ndarray | None = None):
        self.albedo_ratios = np.asarray(ratios, dtype=np.float64)
        self.factors = np.ones_like(self.albedo_ratios) if factors is None else np.asarray(factors, np.float64)
        if self.factors.shape != self.albedo_ratios.shape:
            raise ValueError(f"LobeCalibration: factors of shape {self.factors.shape}, "
                             f"expected the ratios' {self.albedo_ratios.shape}")
        self.ratios = self.albedo_ratios * self.factors
        self.rows, self.nodes = self.ratios.shape
        # Node-major, the rows of one node side by side (padded to a multiple of four): a
        # node's ratios are packet reads, two per lookup node instead of one read per row.
        self.stride = -(-self.rows // 4) * 4
        padded = np.zeros((self.nodes, self.stride))
        padded[:, :self.rows] = self.ratios.T
        self.table = flat_array(padded)

    def scale(self, proxies, cos_theta):
        """The proxies (a list of six per-lane values) times their ratios at ``cos_theta``."""
        x = dr.clip(cos_theta * self.nodes - 0.5, 0.0, self.nodes - 1.0)
        j0 = mi.UInt32(dr.floor(x))
        j1 = dr.minimum(j0 + 1, self.nodes - 1)
        f = x - mi.Float(j0)
        r0 = gather_block(self.table, j0 * self.stride, self.stride)
        r1 = gather_block(self.table, j1 * self.stride, self.stride)
        out = list(proxies)
        for row, (slot, _) in enumerate(CALIBRATED):
            out[slot] = proxies[slot] * dr.lerp(r0[row], r1[row], f)
        return out
