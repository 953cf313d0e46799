"""The fibre-like SGGX normal distribution as one formula over any array type.

Shading (:func:`mscloth.scattering.sggx.ndf`, Dr.Jit arrays) and the NumPy precomputation
of the directional tables (:mod:`mscloth.precompute.tables`) evaluate the same D; both call
this function, so that the tables bin exactly the distribution that shading evaluates. It
imports neither Dr.Jit nor NumPy: plain arithmetic on whatever it is given.
"""
from __future__ import annotations

import math


def fibre_ndf_of_cosines(mt2, m2, alpha):
    """D(m) = alpha^3 / (pi (mt^2 + alpha^2 (|m|^2 - mt^2))^2) of the fibre-like SGGX
    S = alpha^2 t t^T + (I - t t^T), from mt2 = (m.t)^2 and m2 = |m|^2 (1 for unit m).

    The inverse-free form: det S = alpha^2 and adj(S) = t t^T + alpha^2 (I - t t^T), so no
    division by alpha appears."""
    q = mt2 + alpha * alpha * (m2 - mt2)
    return alpha * alpha * alpha / (math.pi * q * q)


def fibre_ndf_mixture(mt2s, m2s, weights, alpha):
    """sum_j weights[j] fibre_ndf_of_cosines(mt2s[j], m2s[j], alpha) (the bilinear mix of
    the direction bins' D) with a division per pair of terms instead of one per term:
    a / p + b / q = (a q + b p) / (p q), p and q the squared denominators, each at least
    alpha^4 |m|^4, so a pair's product stays a normal float32 down to alpha ~ 1e-4."""
    a2 = alpha * alpha
    q2 = [(mt2 + a2 * (m2 - mt2)) ** 2 for mt2, m2 in zip(mt2s, m2s)]
    total = 0.0
    for j in range(0, len(q2) - 1, 2):
        total = total + (weights[j] * q2[j + 1] + weights[j + 1] * q2[j]) / (q2[j] * q2[j + 1])
    if len(q2) % 2:
        total = total + weights[-1] / q2[-1]
    return alpha * a2 / math.pi * total


def fibre_ndf_of_unit_cosine_inplace(mt, alpha, divide):
    """:func:`fibre_ndf_of_cosines` for unit m (|m|^2 = 1) from the cosine mt = m.t,
    computed in place in ``mt`` (an array that supports in-place arithmetic, e.g. NumPy's)
    and returned: the same q = mt^2 + alpha^2 (1 - mt^2) = mt^2 (1 - alpha^2) + alpha^2,
    without a temporary per step (the precomputation's chunks are tens of MiB, and each
    temporary would be another pass over memory: 4-5x the time of this form).
    ``divide(a, x, out=x)``: the array type's in-place a / x (``np.divide``)."""
    a2 = alpha * alpha
    mt *= mt
    mt *= 1.0 - a2
    mt += a2           # q
    mt *= mt           # q^2
    return divide(alpha * alpha * alpha / math.pi, mt, out=mt)


def mean_matrix_sigma(moments, w, alpha, safe_sqrt, maximum):
    """sigma(w) = sqrt(w^T S w) of the mean SGGX matrix S = I - (1 - alpha^2) <t t^T> of a
    set of fibres, from their mean moments <t t^T> = (xx, xy, xz, yy, yz, zz), floored at
    alpha (a single fibre's least projected area). ``safe_sqrt`` and ``maximum`` of the
    array type (e.g. ``dr.safe_sqrt``, ``dr.maximum``)."""
    m_xx, m_xy, m_xz, m_yy, m_yz, m_zz = moments
    alpha2 = alpha * alpha
    q = (w.x * w.x * m_xx + w.y * w.y * m_yy + w.z * w.z * m_zz
         + 2.0 * (w.x * w.y * m_xy + w.x * w.z * m_xz + w.y * w.z * m_yz))
    return safe_sqrt(maximum(1.0 - (1.0 - alpha2) * q, alpha2))
