"""Fibre-like SGGX microflake distribution (Heitz et al. 2015).

For a fibre with unit tangent ``t`` and roughness ``alpha`` the SGGX matrix is

    S = alpha^2 t t^T + (I - t t^T),

i.e. the projected area is ``alpha`` along the fibre and 1 across it; flake
normals concentrate in the plane orthogonal to ``t`` as alpha -> 0
(our roughness convention: alpha^2 along t; see docs/decisions.md).

All functions are pure and work on Dr.Jit arrays of the active variant.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from .fibre_ndf import fibre_ndf_mixture, fibre_ndf_of_cosines, mean_matrix_sigma


def quadratic_form(a, b, t, alpha, ab=None):
    """a^T S b without forming S: a.b - (1 - alpha^2)(a.t)(b.t); ``ab``: a.b if known."""
    return (dr.dot(a, b) if ab is None else ab) - (1.0 - alpha * alpha) * dr.dot(a, t) * dr.dot(b, t)


def projected_area(w, t, alpha, w2=None):
    """sigma(w) = sqrt(w^T S w), the flakes' projected area seen from w (``w2``: |w|^2
    if known, e.g. computed once for many tangents)."""
    return dr.safe_sqrt(quadratic_form(w, w, t, alpha, w2))


def ndf(m, t, alpha, m2=None):
    """D(m) = |det S|^(3/2) / (pi (m^T adj(S) m)^2), the inverse-free form.

    det S = alpha^2 and adj(S) = t t^T + alpha^2 (I - t t^T), so no division
    by alpha appears. Not normalised to 1 over the sphere; what holds is
    integral max(0, w.m) D(m) dm = sigma(w). ``m2``: |m|^2 if known.
    """
    mt = dr.dot(m, t)
    return fibre_ndf_of_cosines(mt * mt, dr.squared_norm(m) if m2 is None else m2, alpha)


def ndf_mixture(ms, t, alpha, weights, m2s=None):
    """sum_j weights[j] D(ms[j]) for one fibre tangent ``t``, with a division per pair of
    terms (:func:`.fibre_ndf.fibre_ndf_mixture`); ``m2s``: the |m_j|^2 if known."""
    mt2s = [dr.square(dr.dot(m, t)) for m in ms]
    return fibre_ndf_mixture(mt2s, [dr.squared_norm(m) for m in ms] if m2s is None else m2s, weights, alpha)


def mean_sigma(moments, w, alpha):
    """sigma(w) of a footprint's mean SGGX matrix S = I - (1 - alpha^2) <t t^T>, from the
    mean moments <t t^T> of its fibres (:func:`.fibre_ndf.mean_matrix_sigma`)."""
    return mean_matrix_sigma(moments, w, alpha, dr.safe_sqrt, dr.maximum)


def sample_visible_normal(wi, t, alpha, sample):
    """Draw a flake normal m from the visible-normal distribution of ``wi``.

    Density: D_wi(m) = max(0, wi.m) D(m) / sigma(wi) (Heitz et al. 2015,
    supplement, Alg. 'sample_VNDF'). ``sample`` is a uniform 2D point.
    """
    # Cosine-distributed point (u, v, w) on the hemisphere around +z.
    r = dr.sqrt(sample.x)
    s, c = dr.sincos(dr.two_pi * sample.y)
    u, v = r * c, r * s
    w = dr.safe_sqrt(1.0 - u * u - v * v)

    # Orthonormal basis (wk, wj, wi) and S expressed in it.
    wk, wj = mi.coordinate_system(wi)
    s_kk = quadratic_form(wk, wk, t, alpha)
    s_jj = quadratic_form(wj, wj, t, alpha)
    s_ii = quadratic_form(wi, wi, t, alpha)
    s_kj = quadratic_form(wk, wj, t, alpha)
    s_ki = quadratic_form(wk, wi, t, alpha)
    s_ji = quadratic_form(wj, wi, t, alpha)

    # det S is rotation invariant: sqrt(det) = alpha.
    sqrt_det = alpha
    inv_sqrt_s_ii = dr.rsqrt(s_ii)
    tmp = dr.safe_sqrt(s_jj * s_ii - s_ji * s_ji)
    inv_tmp = dr.rcp(tmp)

    mk_x = sqrt_det * inv_tmp
    mj_x = -inv_sqrt_s_ii * (s_ki * s_ji - s_kj * s_ii) * inv_tmp
    mj_y = inv_sqrt_s_ii * tmp
    mi_x = inv_sqrt_s_ii * s_ki
    mi_y = inv_sqrt_s_ii * s_ji
    mi_z = inv_sqrt_s_ii * s_ii

    mx = u * mk_x + v * mj_x + w * mi_x
    my = v * mj_y + w * mi_y
    mz = w * mi_z
    m = wk * mx + wj * my + wi * mz
    return dr.normalize(m)


def visible_normal_pdf(wi, m, t, alpha):
    """Density of :func:`sample_visible_normal` (solid angle of m)."""
    return dr.maximum(dr.dot(wi, m), 0.0) * ndf(m, t, alpha) / projected_area(wi, t, alpha)
