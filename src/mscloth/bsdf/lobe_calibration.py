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
1.1-1.4x at the fibre level (docs/decisions.md).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..jit_arrays import flat_array, gather
from .lobes import DIFFUSE_REFLECTION, DIFFUSE_TRANSMISSION, SHEEN, SPECULAR_REFLECTION, SPECULAR_TRANSMISSION

#: Lobes with a measured ratio: (proxy slot, components whose albedos it covers). The
#: specular proxy stands for the flake lobe, which reflects and transmits.
CALIBRATED = ((SHEEN, (SHEEN,)), (SPECULAR_REFLECTION, (SPECULAR_REFLECTION, SPECULAR_TRANSMISSION)),
              (DIFFUSE_REFLECTION, (DIFFUSE_REFLECTION,)), (DIFFUSE_TRANSMISSION, (DIFFUSE_TRANSMISSION,)))
#: No lobe drops below this share of its proxy, so that each stays reachable wherever the
#: measurement saw (nearly) nothing of it.
MIN_RATIO = 0.02


def measure_ratios(bsdf, proxies_at, nodes: int = 16, lanes: int = 1024, seed: int = 0) -> np.ndarray:
    """(len(CALIBRATED), nodes) ratios of mean albedo to mean proxy at cos(theta_i) =
    (j + 1/2) / nodes, over ``lanes`` random texels and azimuths per node (a fixed seed:
    the same BSDF always gets the same table).

    ``proxies_at(si)``: the BSDF's unnormalised proxies (six per-lane values) at the
    fibre-level texels of ``si``."""
    rng = np.random.default_rng(seed)
    mu = np.repeat((np.arange(nodes) + 0.5) / nodes, lanes)
    n = mu.size
    phi = rng.random(n) * 2.0 * np.pi
    sin_t = np.sqrt(1.0 - mu * mu)
    si = dr.zeros(mi.SurfaceInteraction3f, n)  # zero footprint: the fibre-level BSDF
    si.wi = mi.Vector3f(sin_t * np.cos(phi), sin_t * np.sin(phi), mu)
    si.uv = mi.Point2f(rng.random(n), rng.random(n))
    s1 = mi.Float(rng.random(n))
    s2 = mi.Point2f(rng.random(n), rng.random(n))

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


class LobeCalibration:
    """The measured ratios in Dr.Jit memory, interpolated linearly in cos(theta_i)."""

    def __init__(self, ratios: np.ndarray):
        self.ratios = np.asarray(ratios, dtype=np.float64)
        self.rows, self.nodes = self.ratios.shape
        # Node-major, the rows of one node side by side: one cache line per lookup.
        self.table = flat_array(self.ratios.T)

    def scale(self, proxies, cos_theta):
        """The proxies (a list of six per-lane values) times their ratios at ``cos_theta``."""
        x = dr.clip(cos_theta * self.nodes - 0.5, 0.0, self.nodes - 1.0)
        j0 = mi.UInt32(dr.floor(x))
        j1 = dr.minimum(j0 + 1, self.nodes - 1)
        f = x - mi.Float(j0)
        out = list(proxies)
        for row, (slot, _) in enumerate(CALIBRATED):
            r = dr.lerp(gather(self.table, j0 * self.rows + row), gather(self.table, j1 * self.rows + row), f)
            out[slot] = proxies[slot] * r
        return out
