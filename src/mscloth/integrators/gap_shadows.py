"""Shadow rays that pass through the gaps between yarns.

A ``cloth`` surface lets light through its gaps as a delta transmission lobe. BSDF sampling
finds that path to area and environment emitters, but never to a delta emitter (a sun, a
point light): there only emitter sampling can, so its shadow ray must cross the cloth with
the gap transmittance instead of stopping there. For non-delta emitters the shadow ray
stays opaque to cloth: BSDF sampling through the gap already counts that light (with MIS
weight 1, the gap being a delta lobe), and counting it in the shadow ray too would count
it twice.

BSDFs opt in with ``gap_transmission(si, active)``: the fraction of light that crosses the
surface along ``-si.wi`` without scattering (``cloth``: T_sheen^2 times the gap fraction of
the footprint in ``si.duv_dx/dy``, or of the texel). Other surfaces block.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from . import footprint as fp

#: Most cloth layers a shadow ray crosses before it counts as blocked.
MAX_CROSSINGS = 8


def has_gap_transmission(scene) -> bool:
    """Whether any shape of ``scene`` has a BSDF with ``gap_transmission``."""
    return any(hasattr(shape.bsdf(), "gap_transmission") for shape in scene.shapes() if shape.bsdf() is not None)


def _gap_transmission(bsdf, si, active=True):
    if hasattr(bsdf, "gap_transmission"):
        return bsdf.gap_transmission(si, active)
    return mi.Float(0.0)


def shadow_transmittance(scene, si, target, cone_width, cone_spread, active):
    """Transmittance from ``si`` to the point ``target`` through gap-transmitting surfaces
    (0 where anything else blocks), each crossing shaded with the ray cone of the path
    (width ``cone_width`` at ``si``, spread ``cone_spread``) as its footprint."""
    jit = dr.is_jit_v(mi.Float)
    ray = si.spawn_ray_to(target)
    state = (ray, mi.Float(1.0), mi.Bool(active), mi.Float(0.0), mi.UInt32(0))

    def cond(ray, trans, going, travelled, crossings):
        return going

    def body(ray, trans, going, travelled, crossings):
        hit_si = scene.ray_intersect(ray, mi.RayFlags.All, False, going)
        hit = going & hit_si.is_valid()
        d = dr.normalize(ray.d)
        hit_si.wi = hit_si.to_local(-d)
        width = fp.cone_width(cone_width, cone_spread, travelled + hit_si.t)
        hit_si.duv_dx, hit_si.duv_dy = fp.cone_footprint(width, d, hit_si.n, hit_si.dp_du, hit_si.dp_dv)
        if jit:
            crossing = dr.dispatch(hit_si.bsdf(), _gap_transmission, hit_si, hit)
        else:
            # A scalar miss has no shape: asking it for a BSDF dereferences null.
            crossing = _gap_transmission(hit_si.bsdf(), hit_si, hit) if hit else mi.Float(1.0)
        trans = dr.select(hit, trans * crossing, trans)
        crossings = dr.select(hit, crossings + 1, crossings)
        going = hit & (trans > 0.0) & (crossings < MAX_CROSSINGS)
        trans = dr.select(hit & (crossings >= MAX_CROSSINGS), 0.0, trans)
        next_ray = hit_si.spawn_ray_to(target)
        ray = dr.select(going, next_ray, ray) if jit else (next_ray if going else ray)
        travelled = dr.select(hit, travelled + hit_si.t, travelled)
        return ray, trans, going, travelled, crossings

    if jit:
        state = dr.while_loop(state, cond, body, label="gap_shadow")
    else:
        while state[2]:
            state = body(*state)
    return state[1]
