"""Shadow rays that pass through the gaps between yarns.

A ``cloth`` surface lets light through its gaps as a delta transmission lobe: for light
transport the gap is a null interface with transmittance ``gap_transmission``. Emitter
sampling reaches emitters behind cloth as volpath reaches them behind a null surface: the
shadow ray crosses each cloth layer with that transmittance instead of stopping there.
For delta emitters (a sun, a point light) this is the only way their light passes (BSDF
sampling never hits them). For other emitters BSDF sampling also gets there, by choosing
the gap lobe at every crossing; ``clothpath`` then weighs the two strategies by MIS at the
vertex before the crossings (the crossings are transparent to its MIS bookkeeping), so
that light is counted once, mostly by the shadow ray, with far less noise than by BSDF
paths that must hit a small emitter.

BSDFs opt in with ``gap_transmission(si, active)`` (:mod:`.bsdf_contract`): the fraction
of light that crosses the surface along ``-si.wi`` without scattering (``cloth``: T_sheen^2
times the gap fraction of the footprint in ``si.duv_dx/dy``, or of the texel). Other
surfaces block.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..lanes import logical_not
from . import bsdf_contract as contract
from . import footprint as fp

#: Most cloth layers a shadow ray crosses; one more blocks it (BSDF-sampled paths to an
#: emitter across more layers than this are not MIS-weighted against shadow rays).
MAX_CROSSINGS = 8


def gap_bsdfs(scene) -> list:
    """The distinct BSDFs of ``scene``'s shapes that have ``gap_transmission``."""
    return contract.distinct_bsdfs(scene, contract.has_gap_transmission)


def has_gap_transmission(scene) -> bool:
    """Whether any shape of ``scene`` has a BSDF with ``gap_transmission``."""
    return bool(gap_bsdfs(scene))


def is_gap_bsdf(bsdf, found) -> mi.Bool:
    """Whether ``bsdf`` (a ``BSDFPtr`` in JIT variants) is one of ``found`` (those of
    :func:`gap_bsdfs`): pointer comparisons per lane, no dispatch."""
    if not dr.is_jit_v(mi.Float):
        return contract.has_gap_transmission(bsdf)
    on_gap = mi.Bool(False)
    for b in found:
        on_gap |= bsdf == mi.BSDFPtr(b)
    return on_gap



def shadow_transmittance(scene, si, target, cone_width, cone_spread, active,
                         max_crossings=MAX_CROSSINGS):
    """Transmittance from ``si`` to the point ``target`` through gap-transmitting surfaces
    (0 where anything else blocks, or where more than ``max_crossings`` surfaces lie in the
    way), each crossing shaded with the ray cone of the path (width ``cone_width`` at
    ``si``, spread ``cone_spread``) as its footprint."""
    ray = si.spawn_ray_to(target)
    limit = mi.UInt32(max_crossings)
    state = (ray, mi.Float(1.0), mi.Bool(active), mi.Float(0.0), mi.UInt32(0))

    def body(ray, trans, going, travelled, crossings):
        hit_si = scene.ray_intersect(ray, mi.RayFlags.All, False, going)
        hit = going & hit_si.is_valid()
        crossings = dr.select(hit, crossings + 1, crossings)
        blocked = hit & (crossings > limit)
        hit &= logical_not(blocked)
        d = dr.normalize(ray.d)
        hit_si.wi = hit_si.to_local(-d)
        width = fp.cone_width(cone_width, cone_spread, travelled + hit_si.t)
        hit_si.duv_dx, hit_si.duv_dy = fp.cone_footprint(width, d, hit_si.n, hit_si.dp_du, hit_si.dp_dv)
        # (scalar: a miss has no shape, and bsdf() would dereference it)
        bsdf = hit_si.bsdf() if (dr.is_jit_v(mi.Float) or hit) else None
        crossing = contract.call(bsdf, contract.gap_transmission, hit_si, hit, active=hit,
                                 default=mi.Float(1.0))
        trans = dr.select(blocked, 0.0, dr.select(hit, trans * crossing, trans))
        going = hit & (trans > 0.0)
        ray = dr.select(going, hit_si.spawn_ray_to(target), ray)
        travelled = dr.select(hit, travelled + hit_si.t, travelled)
        return ray, trans, going, travelled, crossings

    # A symbolic loop in JIT variants; a Python while loop in scalar ones (``going`` is a
    # Python bool there).
    return dr.while_loop(state, lambda ray, trans, going, travelled, crossings: going, body,
                         label="gap_shadow")[1]
