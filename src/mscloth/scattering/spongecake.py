"""SpongeCake single-scattering layer (Wang et al. 2022) of fibre-like SGGX flakes.

A slab of optical thickness ``T`` filled with flakes of distribution S
(:mod:`.sggx`). With the signed Lambda(w) = sigma(w) / cos(theta_w):

    f_rs = D(h) G_r / (4 |cos i| |cos o|),  G_r = (1 - e^{-T(Li + Lo)}) / (Li + Lo)
    f_ts = D(h) G_t / (4 |cos i| |cos o|),  G_t = (e^{-T Li} - e^{-T|Lo|}) / (|Lo| - Li)

(supplement Eq. 2-6; G_t -> T e^{-T L} as Li -> |Lo|). ``h = normalize(i + o)``
in both cases: a flake reflects, whichever side o leaves on.

Convention: ``wi`` is on the upper side (wi.z > 0); callers mirror two-sided
configurations first. Values returned by ``eval_*`` include |cos o| (Mitsuba's
convention) and exclude albedo.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import drjit as dr

from . import sggx

#: Below this |cos theta| a direction counts as grazing and scatters nothing
#: (a measure-zero set; avoids 0 * inf in Lambda).
COS_EPSILON = 1e-6


def _one_minus_exp_over_x(x, exp_minus_x=None):
    """(1 - e^{-x}) / x for x >= 0, accurate near 0 where the direct form cancels;
    ``exp_minus_x``: e^{-x} if the caller has it."""
    small = x < 1e-2
    series = 1.0 - x * (0.5 - x * (1.0 / 6.0 - x * (1.0 / 24.0)))
    e = dr.exp(-x) if exp_minus_x is None else exp_minus_x
    direct = (1.0 - e) / dr.select(small, 1.0, x)
    return dr.select(small, series, direct)


def unscattered_transmittance(w, t, alpha, thickness):
    """e^{-T |Lambda(w)|}: the fraction crossing the layer along w unscattered."""
    return unscattered_transmittance_from(sggx.projected_area(w, t, alpha), w, thickness)


def unscattered_transmittance_from(sigma, w, thickness):
    """:func:`unscattered_transmittance` given the projected area ``sigma`` = sigma(w) (the
    form multi-scale shading uses with a footprint's mean SGGX matrix). Zero at grazing
    w.z = 0 (Lambda is infinite there), guarded: scalar variants' Python floats raise on /0."""
    grazing = w.z == 0.0
    lam = dr.abs(sigma / dr.select(grazing, 1.0, w.z))
    return dr.select(grazing, 0.0, dr.exp(-thickness * lam))


def reflection_attenuation(lambda_i, lambda_o, thickness):
    """G_r of Eq. 3 for Lambda_i, Lambda_o > 0."""
    s = lambda_i + lambda_o
    return thickness * _one_minus_exp_over_x(thickness * s)


def transmission_attenuation(lambda_i, lambda_o, thickness):
    """G_t of Eq. 6 for Lambda_i > 0 and a signed (negative) Lambda_o.

    Written as e^{-T a} T phi(T (b - a)) with a = min(Li, |Lo|), b = max, which
    is exact, symmetric in (Li, |Lo|) and has the limit T e^{-T L} built in.
    """
    return _attenuations(dr.abs(lambda_i), dr.abs(lambda_o), thickness)[1]


def _attenuations(lam_i, lam_o, thickness):
    """(e^{-T (Li + Lo)}, G_t) for Li, Lo >= 0, from two exponentials: e^{-T a} with
    a = min(Li, Lo), and e^{-x} with x = T (b - a), b = max(Li, Lo). G_t is
    e^{-T a} T phi(x) (:func:`transmission_attenuation`) and G_r's exponent T (Li + Lo) is
    2 T a + x, so a shading point evaluates both lobes with two exponentials, not three."""
    a = dr.minimum(lam_i, lam_o)
    b = dr.maximum(lam_i, lam_o)
    e_a = dr.exp(-thickness * a)
    x = thickness * (b - a)
    e_x = dr.exp(-x)
    return e_a * e_a * e_x, e_a * thickness * _one_minus_exp_over_x(x, e_x)


def eval_specular(wi, wo, t, alpha, thickness):
    """f_rs or f_ts times |cos o| (no albedo), chosen by the side of ``wo``.

    Returns (value, is_reflection). Zero at grazing directions.
    """
    return eval_specular_transmittance(wi, wo, t, alpha, thickness)[:2]


def eval_specular_transmittance(wi, wo, t, alpha, thickness):
    """:func:`eval_specular` and e^{-T (|Lambda(i)| + |Lambda(o)|)}, the share of light that
    crosses the layer unscattered both ways, which the evaluation computes anyway (the
    sheen: T_sheen(i) T_sheen(o), the fuzz the yarn lobes' light passes)."""
    h = dr.normalize(wi + wo)
    d = sggx.ndf(h, t, alpha)
    sigma_i = sggx.projected_area(wi, t, alpha)
    sigma_o = sggx.projected_area(wo, t, alpha)
    return _eval_specular(d, sigma_i, sigma_o, wi, wo, thickness)


def eval_specular_from(d, sigma_i, sigma_o, wi, wo, thickness):
    """:func:`eval_specular` given the flake density ``d`` = D(h) and the projected
    areas sigma(wi), sigma(wo): the form multi-scale shading uses with footprint-averaged
    D and sigma."""
    return _eval_specular(d, sigma_i, sigma_o, wi, wo, thickness)[:2]


@dataclass
class SpecularDirections:
    """What the specular evaluation at one pair (wi, wo) shares between flake
    distributions (:func:`eval_specular_at`; a footprint's residual texels evaluate
    many): where it is defined, the side wo leaves on, and the cosines, with their
    inverses (one division per pair instead of three per tangent)."""

    valid: Any
    #: :func:`half_vector_defined`.
    finite: Any
    reflect: Any
    cos_i: Any
    abs_cos_o: Any
    inv_cos_i: Any
    inv_cos_o: Any

    @staticmethod
    def of(wi, wo) -> SpecularDirections:
        cos_i = wi.z
        abs_cos_o = dr.abs(wo.z)
        valid = directions_valid(wi, wo)
        return SpecularDirections(valid=valid, finite=half_vector_defined(wi, wo), reflect=wo.z > 0.0,
                                  cos_i=cos_i, abs_cos_o=abs_cos_o,
                                  inv_cos_i=1.0 / dr.select(valid, cos_i, 1.0),
                                  inv_cos_o=1.0 / dr.select(valid, abs_cos_o, 1.0))


def eval_specular_at(d, sigma_i, sigma_o, dirs: SpecularDirections, thickness):
    """:func:`eval_specular_from` at directions ``dirs`` (:meth:`SpecularDirections.of`)."""
    return _eval_specular_at(d, sigma_i, sigma_o, dirs, thickness)[0]


def _eval_specular_at(d, sigma_i, sigma_o, dirs: SpecularDirections, thickness):
    """(value, unscattered both ways) of :func:`eval_specular_at`."""
    # Reflection: G_r / cos_i = (1 - e^{-T s}) |cos o| / (sigma_i |cos o| + sigma_o cos i),
    # a form that stays finite at grazing angles.
    unscattered, g_t = _attenuations(sigma_i * dirs.inv_cos_i, sigma_o * dirs.inv_cos_o, thickness)
    # (The denominator is > 0 where valid; guarded elsewhere, where a zero wo makes it 0.)
    g_r_over_cos_i = ((1.0 - unscattered) * dirs.abs_cos_o
                      / dr.select(dirs.valid, sigma_i * dirs.abs_cos_o + sigma_o * dirs.cos_i, 1.0))
    g_over_cos_i = dr.select(dirs.reflect, g_r_over_cos_i, g_t * dirs.inv_cos_i)
    return dr.select(dirs.valid & dirs.finite, 0.25 * d * g_over_cos_i, 0.0), unscattered


def _eval_specular(d, sigma_i, sigma_o, wi, wo, thickness):
    """(value, is_reflection, unscattered both ways) of :func:`eval_specular_from`."""
    dirs = SpecularDirections.of(wi, wo)
    value, unscattered = _eval_specular_at(d, sigma_i, sigma_o, dirs, thickness)
    return value, dirs.reflect, unscattered


def sample_specular(wi, t, alpha, sample):
    """Sample wo by reflecting wi on a visible flake normal.

    Returns (wo, pdf) with pdf(wo) = D(h) / (4 sigma(wi)); wo may leave on
    either side (reflection or transmission).
    """
    m = sggx.sample_visible_normal(wi, t, alpha, sample)
    wo = 2.0 * dr.dot(wi, m) * m - wi
    return wo, pdf_specular(wi, wo, t, alpha)


def pdf_specular(wi, wo, t, alpha):
    """Solid-angle density of :func:`sample_specular`."""
    h, valid = specular_half_vector(wi, wo)
    return pdf_specular_from(sggx.ndf(h, t, alpha), sggx.projected_area(wi, t, alpha), valid)


def specular_half_vector(wi, wo):
    """(h, valid) of :func:`pdf_specular`: the half vector, and where the density is
    defined (then sigma(wi) > 0)."""
    return dr.normalize(wi + wo), half_vector_defined(wi, wo) & (wi.z > COS_EPSILON)


def directions_valid(wi, wo):
    """Where the layer's BSDF is evaluated: the viewer above the surface plane and the
    outgoing direction off it, both beyond COS_EPSILON (grazing ones scatter nothing)."""
    return (wi.z > COS_EPSILON) & (dr.abs(wo.z) > COS_EPSILON)


def half_vector_defined(wi, wo):
    """Whether the half vector of (wi, wo) is defined: wi == -wo leaves it none (a
    direction of measure zero)."""
    return dr.squared_norm(wi + wo) > 1e-12


def pdf_specular_from(d, sigma_i, valid):
    """:func:`pdf_specular` given D(h) and sigma(wi), and its ``valid`` from
    :func:`specular_half_vector` (the form for many tangents at one pair of directions).
    Guarded: scalar floats raise on /0."""
    return dr.select(valid, d / dr.select(valid, 4.0 * sigma_i, 1.0), 0.0)
