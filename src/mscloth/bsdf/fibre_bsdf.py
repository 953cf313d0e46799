"""The fibre-level ``cloth`` BSDF (supplement Eq. 1-8) at one texel of the cloth maps:
the view frame, texel reads, the lobes' eval, density and sampling, and the height field's
visibility. The footprint estimator (:mod:`.footprint_estimator`) builds on the same pieces.

Variant-agnostic, as Mitsuba's ``MicrofacetDistribution`` is to its plugins: one class
for every variant, reading ``mi`` and ``dr`` of the variant active when called; the
per-variant plugin (:mod:`.cloth`) holds one and wires Mitsuba's interface to it.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np

from ..jit_arrays import Extent, flat_array, gather_block, opaque
from ..scattering import sheen, spongecake
from .lobe_mixture import LobeSamplers, lobe_proxies, lobe_weights
from .lobes import DIFFUSE_REFLECTION, DIFFUSE_TRANSMISSION, SHEEN, SPECULAR_REFLECTION, SPECULAR_TRANSMISSION
from .shading_state import LobeAlbedos, Texel, ViewFrame


@dataclass
class ShadingParameters:
    """The parameters shading reads live (``mi.traverse`` exposes them; the plugin keeps
    them opaque, see :meth:`.cloth.ClothBSDF.parameters_changed`). What the tables were
    built from is :class:`.parameters.BuildParameters`, apart."""

    uv_scale: Any
    uv_scale_v: Any
    roughness: Any
    thickness: Any
    sheen_roughness: Any
    sheen_thickness: Any
    #: Spectrum parameters by name (``specular_albedo``, ...): Mitsuba textures.
    textures: dict = field(default_factory=dict)

    def albedos(self, si, active) -> LobeAlbedos:
        return LobeAlbedos(**{name: tex.eval(si, active) for name, tex in self.textures.items()})


@dataclass
class TileTables:
    """The cloth maps in Dr.Jit memory: texel (ix, iy)'s four channels at 4 (iy W + ix),
    one packet read per texel, at the index the visibility and cluster tables use too.

    Traced code reads the tile's size (``width``, ``height``) and the uniform yarn colour
    as opaque values, not literals: cloths that differ only in them (tile resolutions,
    yarn colours) then trace the same code, one callable in a render's kernel instead of
    one each (docs/performance-log.md L23)."""

    #: (tangent x, y, z, yarn coverage) per texel.
    fibre: Any
    #: (yarn albedo r, g, b, height) per texel.
    color: Any
    tile_w: int
    tile_h: int
    #: The one yarn colour of uniformly coloured yarns (the common case: no albedo reads,
    #: per texel or from the SATs), else None.
    uniform_yarn_albedo: list | None

    def __post_init__(self):
        self.width, self.height = Extent(self.tile_w), Extent(self.tile_h)
        #: :attr:`uniform_yarn_albedo` as an opaque Color3f (None where yarn colours vary).
        self.uniform_yarn_colour = None
        if self.uniform_yarn_albedo is not None:
            self.uniform_yarn_colour = mi.Color3f(*(opaque(mi.Float, c) for c in self.uniform_yarn_albedo))

    @staticmethod
    def from_maps(maps) -> TileTables:
        fibre = np.concatenate([maps.tangent, maps.gap[..., None]], axis=-1).astype(np.float32)
        color = np.concatenate([maps.albedo, maps.height[..., None]], axis=-1).astype(np.float32)
        tile_h, tile_w = maps.resolution
        # A gap texel's colour multiplies nothing: its yarn lobes are 0.
        yarn_colours = maps.albedo[maps.gap > 0]
        uniform = None
        if len(yarn_colours) and np.all(yarn_colours == yarn_colours[0]):
            uniform = [float(c) for c in yarn_colours[0]]
        return TileTables(flat_array(fibre), flat_array(color), tile_w, tile_h, uniform)


def edges_in_texels(uv_scale, uv_scale_v, tile: TileTables, si):
    """The pixel footprint's edges si.duv_dx, si.duv_dy in texels of the tile."""
    su, sv = uv_scale * tile.width.f, uv_scale_v * tile.height.f
    return (si.duv_dx.x * su, si.duv_dx.y * sv), (si.duv_dy.x * su, si.duv_dy.y * sv)


class FibreBSDF:
    """Fibre-level shading at a texel: ``params`` (live), ``tile`` (the maps), the
    lobe ``samplers`` and ``calibration`` (set by the plugin), and ``footprint_data``
    (the precomputed tables, for visibility and parallax; None without them)."""

    def __init__(self, params: ShadingParameters, tile: TileTables, use_visibility: bool, use_parallax: bool):
        self.params = params
        self.tile = tile
        self.use_visibility = use_visibility
        self.use_parallax = use_parallax
        self.footprint_data = None
        self.samplers: LobeSamplers | None = None
        #: :class:`.lobe_calibration.LobeCalibration` of the lobe choice (None: raw proxies).
        self.calibration = None

    # ------------------------------------------------------------------
    # Shading state: the viewer's frame, a texel
    # ------------------------------------------------------------------
    def frame(self, si, active, pixel_offset=None, pixel_filter="box") -> ViewFrame:
        """What of the shading point does not depend on the texel, in the mirrored frame
        where the viewer is above the surface."""
        p, tile = self.params, self.tile
        flip = si.wi.z < 0.0
        sign = dr.select(flip, -1.0, 1.0)
        wi = mi.Vector3f(si.wi.x, si.wi.y, sign * si.wi.z)
        t_sheen_i = sheen.sheen_transmittance(wi, p.sheen_roughness, p.sheen_thickness)
        # Texel coordinates of si.uv: one tile is tile_w x tile_h texels.
        x = si.uv.x * p.uv_scale * tile.width.f
        y = si.uv.y * p.uv_scale_v * tile.height.f
        # A mesh's non-finite uv (the loader refuses them; user code may not) shades as
        # texel (0, 0) rather than spreading NaN through the tables' arithmetic.
        x, y = dr.select(dr.isfinite(x), x, 0.0), dr.select(dr.isfinite(y), y, 0.0)
        if self.use_parallax:
            # Look up (and centre the footprint on) the texel the view ray reaches
            # first in the height field; the table covers the front side only.
            ix, iy = self.texel_index(mi.Point2f(x * tile.width.rcp, y * tile.height.rcp))
            dx, dy = self.footprint_data.parallax_offset(ix, iy, wi)
            x = dr.select(flip, x, x + dx)
            y = dr.select(flip, y, y + dy)
        return ViewFrame(flip=flip, sign=sign, wi=wi, k=p.albedos(si, active), t_sheen_i=t_sheen_i, x=x, y=y,
                         active=active, pixel_offset=pixel_offset, pixel_filter=pixel_filter)

    def texel_index(self, pos):
        """The texel (ix, iy) that nearest lookups at tile coordinates ``pos`` read
        (periodic)."""
        w, h = self.tile.width, self.tile.height
        ix = mi.UInt32(dr.clip(dr.floor((pos.x - dr.floor(pos.x)) * w.f), 0, w.last_f))
        iy = mi.UInt32(dr.clip(dr.floor((pos.y - dr.floor(pos.y)) * h.f), 0, h.last_f))
        return ix, iy

    def texel(self, fr: ViewFrame, x, y) -> Texel:
        """The fibre-level state at texel coordinates (x, y) (periodic)."""
        tile = self.tile
        ix, iy = self.texel_index(mi.Point2f(x * tile.width.rcp, y * tile.height.rcp))
        start = (iy * tile.width.u + ix) * 4
        fibre = gather_block(tile.fibre, start, 4, fr.active)
        if tile.uniform_yarn_colour is not None:
            color = tile.uniform_yarn_colour
        else:
            color = mi.Color3f(*gather_block(tile.color, start, 4, fr.active)[:3])
        tangent = mi.Vector3f(fibre[0], fibre[1], fr.sign * fibre[2])
        return Texel(frame=fr, tangent=tangent, yarn=fibre[3], k=fr.k.with_yarn_albedo(color), ix=ix, iy=iy,
                     color=color)

    # ------------------------------------------------------------------
    # The lobe mixture at a texel
    # ------------------------------------------------------------------
    def scattered(self, pt: Texel):
        """The share of light the texel's specular slab scatters (for its proxy)."""
        p = self.params
        return 1.0 - spongecake.unscattered_transmittance(pt.wi, pt.tangent, p.roughness, p.thickness)

    def lobe_probabilities(self, pt: Texel, enabled) -> list:
        """Selection probabilities of the texel's lobes, proportional to each lobe's
        estimated albedo."""
        return lobe_weights(pt.k, pt.wi, pt.yarn, pt.t_sheen_i, self.scattered(pt), enabled, self.calibration)

    def point_proxies(self, si) -> list:
        """Unnormalised lobe proxies of the fibre-level texels of ``si`` (calibration)."""
        fr = self.frame(si, True)
        pt = self.texel(fr, fr.x, fr.y)
        return lobe_proxies(pt.k, pt.wi, pt.yarn, pt.t_sheen_i, self.scattered(pt), [True] * 6)

    # ------------------------------------------------------------------
    # Visibility of the height field
    # ------------------------------------------------------------------
    @staticmethod
    def outgoing_side(flip, wo):
        """(wo folded up, back?) for the visibility tables: the outgoing direction
        (mirrored frame) sees the viewer's side for reflection, the other side for
        transmission."""
        return mi.Vector3f(wo.x, wo.y, dr.abs(wo.z)), flip == (wo.z > 0.0)

    def read_visibility(self, pt: Texel) -> Texel:
        """The texel with its visibility bits, read once for every direction."""
        if self.use_visibility and self.footprint_data is not None:
            pt.vis = self.footprint_data.texel_visibility(pt.ix, pt.iy)
        return pt

    def visibility_o(self, pt: Texel, wo):
        """V(p, o) of the texel for the outgoing direction (mirrored frame)."""
        wo_up, back = self.outgoing_side(pt.flip, wo)
        return self.footprint_data.visibility_of(pt.vis, wo_up, back)

    def visibility(self, pt: Texel, wo):
        """V(p, i, o) of the texel: shadowing x masking by the cloth's height field.
        The viewer's side uses the front table, mirrored when the viewer is below."""
        if self.footprint_data is None:
            return mi.Float(1.0)
        v_i = self.footprint_data.visibility_of(pt.vis, pt.wi, pt.flip)
        return v_i * self.visibility_o(pt, wo)

    def cluster_visibilities_o(self, fr: ViewFrame, wo):
        """Every cluster's mean V for the outgoing direction (mirrored frame)."""
        return self.footprint_data.cluster_visibilities(*self.outgoing_side(fr.flip, wo))

    # ------------------------------------------------------------------
    # Eval, pdf, sample (mirrored frame)
    # ------------------------------------------------------------------
    def sheen_and_fuzz(self, fr: ViewFrame, wo, enabled):
        """(f_sheen |cos o| k_sheen, T_sheen(i) T_sheen(o)) for the outgoing direction:
        the fuzz's reflection and what crosses it both ways; the second comes with the
        first's exponentials when the sheen is evaluated."""
        p = self.params
        if enabled[SHEEN]:
            f_sheen, fuzz = sheen.eval_sheen_transmittance(fr.wi, wo, p.sheen_roughness, p.sheen_thickness)
            return f_sheen * fr.k.sheen_color, fuzz
        fuzz = fr.t_sheen_i * sheen.sheen_transmittance(wo, p.sheen_roughness, p.sheen_thickness)
        return mi.Color3f(0.0), fuzz

    def eval_pdf(self, pt: Texel, wo, enabled, probs):
        """Non-delta f*|cos o| and pdf of the texel, for lobe probabilities ``probs``."""
        p = self.params
        wi, t, yarn, k = pt.wi, pt.tangent, pt.yarn, pt.k
        cos_o = wo.z
        up = cos_o > 0.0
        valid = spongecake.directions_valid(wi, wo)
        value, fuzz = self.sheen_and_fuzz(pt.frame, wo, enabled)
        under_fuzz = fuzz * yarn
        spec = None
        if enabled[SPECULAR_REFLECTION] or enabled[SPECULAR_TRANSMISSION]:
            spec, _ = spongecake.eval_specular(wi, wo, t, p.roughness, p.thickness)
        yarn_lobes = self.yarn_lobes(k, spec, dr.abs(cos_o) * dr.inv_pi, up, enabled)
        if self.use_visibility:
            yarn_lobes *= self.visibility(pt, wo)
        value += under_fuzz * yarn_lobes
        value = dr.select(valid, value, 0.0)
        pdf = dr.select(valid, self.samplers.pdf(p.roughness, wi, wo, probs, [t], enabled,
                                                            self.samplers.fold_share(k, enabled)), 0.0)
        return value, pdf

    @staticmethod
    def yarn_lobes(k, spec, cosine, up, enabled):
        """The yarn's lobes (f |cos o|, before visibility and the fuzz above them) on the side
        ``up`` tells, given albedos ``k``, the flakes' specular value ``spec`` (None when
        no specular lobe is enabled) and |cos o| / pi ``cosine``."""
        reflection = mi.Color3f(0.0)
        transmission = mi.Color3f(0.0)
        if spec is not None:
            if enabled[SPECULAR_REFLECTION]:
                reflection += k.specular_albedo * spec
            if enabled[SPECULAR_TRANSMISSION]:
                transmission += k.specular_transmittance * spec
        if enabled[DIFFUSE_REFLECTION]:
            reflection += k.diffuse_albedo * cosine
        if enabled[DIFFUSE_TRANSMISSION]:
            transmission += k.diffuse_transmittance * cosine
        return dr.select(up, reflection, transmission)

    def sample(self, pt: Texel, probs, enabled, sample1, sample2, active, strata: int = 1):
        """A direction from the texel's lobe mixture: (wo, ok, component, gap_ok);
        ``strata`` as in :meth:`.LobeSamplers.sample`."""
        return self.samplers.sample(self.params.roughness, pt.wi, pt.tangent, probs, enabled, sample1, sample2,
                                    active, self.samplers.fold_share(pt.k, enabled), strata)

    def gap_value(self, fr: ViewFrame, yarn):
        """What the gap lets through straight: T_sheen(i)^2 (1 - I)."""
        return fr.t_sheen_i * fr.t_sheen_i * (1.0 - yarn)
