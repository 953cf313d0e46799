"""Sheen: a thin layer of fuzz fibres standing along the normal (our reading of
the paper, after Zeltner, Burley & Chiang 2022).

The fuzz is a SpongeCake layer of fibre-like SGGX flakes with tangent n = +z,
its own roughness ``alpha_s`` and optical thickness ``T_s``. It reflects by
single scattering, and what passes it unscattered both ways,

    T_sheen(i, o) = e^{-T_s |Lambda_s(i)|} e^{-T_s |Lambda_s(o)|},

reaches the cloth below (Eq. 1).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from . import spongecake


def _up(w):
    """The fuzz fibres' tangent: the macro normal (broadcasts to w's width)."""
    return mi.Vector3f(0.0, 0.0, 1.0)


def eval_sheen(wi, wo, alpha_s, thickness_s):
    """Sheen reflection f_sheen times |cos o| (no colour); zero for wo below."""
    value, reflect = spongecake.eval_specular(wi, wo, _up(wi), alpha_s, thickness_s)
    return dr.select(reflect, value, 0.0)


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
