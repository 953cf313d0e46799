"""The ``cloth`` BSDF plugin: wires cloth maps and parameters into the lobes of
supplement Eq. 1. The scattering maths lives in :mod:`mscloth.scattering`.

Plugin classes bind to the Mitsuba variant active when they are defined, so
:func:`make_cloth_class` builds one class per variant (see :mod:`.registry`).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..maps.builtin import resolve_pattern
from ..scattering import sheen, spongecake
from .parameters import FLOAT_PARAMETERS, SPECTRUM_PARAMETERS, read_parameters

# Component indices, in the order of ``m_components``.
SHEEN, SPECULAR_REFLECTION, DIFFUSE_REFLECTION, SPECULAR_TRANSMISSION, DIFFUSE_TRANSMISSION, GAP = range(6)
LOBE_NAMES = ("sheen", "specular_reflection", "diffuse_reflection",
              "specular_transmission", "diffuse_transmission", "gap")

DOCSTRING = r"""
Multi-scale surface-based cloth (``cloth``)
-------------------------------------------

Fibre-level cloth BSDF of Zhu et al. 2024 (supplement Eq. 1-8): a sheen layer
of fuzz over a SpongeCake layer of fibre-like SGGX flakes whose tangents come
from cloth maps, with diffuse lobes for light scattered many times inside the
yarns and delta transmission through the gaps between yarns::

    f = f_sheen + T_sheen I (f_rs + f_rd) + T_sheen I (f_ts + f_td) + T_sheen (1 - I) f_delta

The cloth is thin and two-sided: viewer and light may be on either side; the
back side sees the same maps mirrored through the surface.

.. list-table::
   :header-rows: 1

   * - Parameter
     - Type
     - Default
     - Meaning
   * - pattern
     - string
     - ``plain``
     - Cloth maps: a pattern name (``plain``, ``twill-2-1``, ``satin-8-3``,
       ``basket-2``, ``jersey``, ``rib-2-2``...), a ``.wif`` draft file, or a
       directory written by ``ClothMaps.save`` / ``mscloth maps``.
   * - resolution
     - integer
     - 0
     - Texels along u when generating a pattern (0: 64 per thread, in [64, 1024]).
   * - uv_scale
     - float
     - 1.0
     - Pattern tiles per UV unit, > 0 (along u, and along v unless
       ``uv_scale_v`` is given).
   * - uv_scale_v
     - float
     - 0
     - Pattern tiles per UV unit along v (0: ``uv_scale`` times the tile's
       width / height, so a square UV unit shows the weave at its true aspect); e.g.
       a Mitsuba ``sphere`` (u spans twice the length of v) wants half of that.
   * - roughness
     - float
     - 0.3
     - Fibre roughness alpha in (0, 1]: the SGGX matrix is
       alpha^2 t t^T + (I - t t^T) for fibre tangent t.
   * - thickness
     - float
     - 2.0
     - Optical thickness T > 0 of the yarn layer.
   * - specular_albedo
     - spectrum or texture
     - 0.4
     - k_rs in [0, 1], multiplied by the maps' yarn albedo.
   * - specular_transmittance
     - spectrum or texture
     - 0.2
     - k_ts in [0, 1], multiplied by the maps' yarn albedo.
   * - diffuse_albedo
     - spectrum or texture
     - 0.4
     - k_rd in [0, 1], multiplied by the maps' yarn albedo.
   * - diffuse_transmittance
     - spectrum or texture
     - 0.1
     - k_td in [0, 1], multiplied by the maps' yarn albedo.
   * - sheen_color
     - spectrum or texture
     - 0.5
     - Albedo of the fuzz fibres, in [0, 1].
   * - sheen_roughness
     - float
     - 0.5
     - Roughness of the fuzz fibres (standing along the normal), in (0, 1].
   * - sheen_thickness
     - float
     - 0.2
     - Optical thickness of the fuzz, >= 0 (0 disables sheen).

Per channel, diffuse_albedo + diffuse_transmittance + max(specular_albedo,
specular_transmittance) must not exceed 1, so that no configuration creates
energy. Components (for ``BSDFContext.component``): 0 sheen, 1 specular
reflection, 2 diffuse reflection, 3 specular transmission, 4 diffuse
transmission, 5 gap (delta transmission).
"""


def _max_channel(c):
    return dr.maximum(dr.maximum(c[0], c[1]), c[2])


def make_cloth_class():
    """Define the ``cloth`` BSDF class for the active Mitsuba variant."""

    both_sides = mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide
    varying = mi.BSDFFlags.SpatiallyVarying
    lobe_flags = (
        mi.BSDFFlags.GlossyReflection | both_sides,
        mi.BSDFFlags.GlossyReflection | both_sides | varying,
        mi.BSDFFlags.DiffuseReflection | both_sides | varying,
        mi.BSDFFlags.GlossyTransmission | both_sides | varying,
        mi.BSDFFlags.DiffuseTransmission | both_sides | varying,
        mi.BSDFFlags.DeltaTransmission | both_sides | varying,
    )
    lobe_types = (
        mi.BSDFFlags.GlossyReflection, mi.BSDFFlags.GlossyReflection, mi.BSDFFlags.DiffuseReflection,
        mi.BSDFFlags.GlossyTransmission, mi.BSDFFlags.DiffuseTransmission, mi.BSDFFlags.DeltaTransmission,
    )

    class ClothBSDF(mi.BSDF):
        __doc__ = DOCSTRING

        def __init__(self, props):
            # Validate everything before the C++ base is constructed: a base that is
            # constructed (and registered for virtual calls) by an __init__ that then raises
            # leaves a dangling registry entry, and a later render crashes on it.
            p = read_parameters(props)
            maps = resolve_pattern(p.pattern, p.resolution)
            mi.BSDF.__init__(self, props)
            self.pattern = p.pattern
            self.maps = maps
            self.uv_scale = mi.Float(p.uv_scale)
            # Square UV units see the tile at its physical aspect unless told otherwise.
            width_mm, height_mm = self.maps.meta.get("tile_size_mm", (1.0, 1.0))
            self.uv_scale_v = mi.Float(p.uv_scale_v or p.uv_scale * width_mm / height_mm)
            self.roughness = mi.Float(p.roughness)
            self.thickness = mi.Float(p.thickness)
            self.sheen_roughness = mi.Float(p.sheen_roughness)
            self.sheen_thickness = mi.Float(p.sheen_thickness)
            self.textures = p.textures
            self._upload_maps(self.maps)

            flags = 0
            for f in lobe_flags:
                flags |= f
            self.m_components = list(lobe_flags)
            self.m_flags = flags

        def _upload_maps(self, maps):
            fibre = np.concatenate([maps.tangent, maps.gap[..., None]], axis=-1).astype(np.float32)
            color = np.concatenate([maps.albedo, maps.height[..., None]], axis=-1).astype(np.float32)
            kwargs = dict(filter_mode=dr.FilterMode.Nearest, wrap_mode=dr.WrapMode.Repeat)
            # Nearest lookups: the fibre-level BSDF sees exactly one texel.
            self.fibre_texture = mi.Texture2f(mi.TensorXf(fibre), **kwargs)
            self.color_texture = mi.Texture2f(mi.TensorXf(color), **kwargs)

        # ------------------------------------------------------------------
        # Shading-point state shared by sample / eval / pdf
        # ------------------------------------------------------------------
        def _point(self, ctx, si, active):
            """Everything that depends on the shading point and wi, in the mirrored
            frame where the viewer is above the surface."""
            flip = si.wi.z < 0.0
            sign = dr.select(flip, -1.0, 1.0)
            wi = mi.Vector3f(si.wi.x, si.wi.y, sign * si.wi.z)

            pos = mi.Point2f(si.uv.x * self.uv_scale, si.uv.y * self.uv_scale_v)
            fibre = self.fibre_texture.eval(pos, active)
            color = self.color_texture.eval(pos, active)
            tangent = mi.Vector3f(fibre[0], fibre[1], sign * fibre[2])
            yarn = fibre[3]                       # I(x): 1 on a yarn, 0 in a gap
            yarn_albedo = mi.Color3f(color[0], color[1], color[2])

            k = {name: self.textures[name].eval(si, active) for name in SPECTRUM_PARAMETERS}
            for name in ("specular_albedo", "specular_transmittance", "diffuse_albedo", "diffuse_transmittance"):
                k[name] = k[name] * yarn_albedo
            t_sheen_i = sheen.sheen_transmittance(wi, self.sheen_roughness, self.sheen_thickness)
            return dict(flip=flip, sign=sign, wi=wi, tangent=tangent, yarn=yarn, k=k, t_sheen_i=t_sheen_i)

        def _enabled(self, ctx):
            return [ctx.is_enabled(lobe_types[c], c) for c in range(6)]

        def _lobe_probabilities(self, ctx, pt, enabled):
            """Selection probabilities, proportional to each lobe's estimated albedo."""
            k, wi, yarn, ts = pt["k"], pt["wi"], pt["yarn"], pt["t_sheen_i"]
            zero = dr.zeros(mi.Float, dr.width(wi))
            w = [zero] * 6
            if enabled[SHEEN]:
                w[SHEEN] = _max_channel(k["sheen_color"]) * (1.0 - ts)
            spec = zero
            if enabled[SPECULAR_REFLECTION]:
                spec = _max_channel(k["specular_albedo"])
            if enabled[SPECULAR_TRANSMISSION]:
                spec = dr.maximum(spec, _max_channel(k["specular_transmittance"]))
            scattered = 1.0 - spongecake.unscattered_transmittance(wi, pt["tangent"], self.roughness, self.thickness)
            w[SPECULAR_REFLECTION] = ts * yarn * spec * scattered
            if enabled[DIFFUSE_REFLECTION]:
                w[DIFFUSE_REFLECTION] = ts * yarn * _max_channel(k["diffuse_albedo"])
            if enabled[DIFFUSE_TRANSMISSION]:
                w[DIFFUSE_TRANSMISSION] = ts * yarn * _max_channel(k["diffuse_transmittance"])
            if enabled[GAP]:
                w[GAP] = ts * ts * (1.0 - yarn)
            total = w[0] + w[1] + w[2] + w[3] + w[4] + w[5]
            inv = dr.select(total > 0.0, dr.rcp(total), 0.0)
            return [wk * inv for wk in w]

        def _eval_pdf_local(self, ctx, pt, wo, enabled, probs, want_pdf=True):
            """Non-delta f*|cos o| and pdf for a mirrored-frame outgoing direction."""
            wi, t, yarn, k = pt["wi"], pt["tangent"], pt["yarn"], pt["k"]
            cos_o = wo.z
            up = cos_o > 0.0
            valid = (wi.z > spongecake.COS_EPSILON) & (dr.abs(cos_o) > spongecake.COS_EPSILON)
            value = mi.Color3f(0.0)
            pdf = mi.Float(0.0)

            if enabled[SHEEN]:
                value += sheen.eval_sheen(wi, wo, self.sheen_roughness, self.sheen_thickness) * k["sheen_color"]
                if want_pdf:
                    pdf += probs[SHEEN] * dr.select(up, sheen.pdf_sheen(wi, wo, self.sheen_roughness), 0.0)

            under_fuzz = pt["t_sheen_i"] * sheen.sheen_transmittance(wo, self.sheen_roughness, self.sheen_thickness) * yarn
            reflection = mi.Color3f(0.0)
            transmission = mi.Color3f(0.0)
            if enabled[SPECULAR_REFLECTION] or enabled[SPECULAR_TRANSMISSION]:
                spec, _ = spongecake.eval_specular(wi, wo, t, self.roughness, self.thickness)
                if enabled[SPECULAR_REFLECTION]:
                    reflection += k["specular_albedo"] * spec
                if enabled[SPECULAR_TRANSMISSION]:
                    transmission += k["specular_transmittance"] * spec
                if want_pdf:
                    side_ok = (up & enabled[SPECULAR_REFLECTION]) | (~up & enabled[SPECULAR_TRANSMISSION])
                    pdf += probs[SPECULAR_REFLECTION] * dr.select(
                        side_ok, spongecake.pdf_specular(wi, wo, t, self.roughness), 0.0)
            cosine = dr.abs(cos_o) * dr.inv_pi
            if enabled[DIFFUSE_REFLECTION]:
                reflection += k["diffuse_albedo"] * cosine
                if want_pdf:
                    pdf += probs[DIFFUSE_REFLECTION] * dr.select(up, cosine, 0.0)
            if enabled[DIFFUSE_TRANSMISSION]:
                transmission += k["diffuse_transmittance"] * cosine
                if want_pdf:
                    pdf += probs[DIFFUSE_TRANSMISSION] * dr.select(up, 0.0, cosine)
            value += under_fuzz * dr.select(up, reflection, transmission)
            value = dr.select(valid, value, 0.0)
            pdf = dr.select(valid, pdf, 0.0)
            return value, pdf

        def _mirror(self, pt, wo):
            return mi.Vector3f(wo.x, wo.y, pt["sign"] * wo.z)

        # ------------------------------------------------------------------
        # mi.BSDF interface
        # ------------------------------------------------------------------
        def sample(self, ctx, si, sample1, sample2, active=True):
            enabled = self._enabled(ctx)
            pt = self._point(ctx, si, active)
            probs = self._lobe_probabilities(ctx, pt, enabled)
            wi, t = pt["wi"], pt["tangent"]

            c_sheen = probs[SHEEN]
            c_spec = c_sheen + probs[SPECULAR_REFLECTION]
            c_dr = c_spec + probs[DIFFUSE_REFLECTION]
            c_dt = c_dr + probs[DIFFUSE_TRANSMISSION]
            c_all = c_dt + probs[GAP]
            pick_sheen = sample1 < c_sheen
            pick_spec = ~pick_sheen & (sample1 < c_spec)
            pick_dr = ~pick_sheen & ~pick_spec & (sample1 < c_dr)
            pick_dt = ~pick_sheen & ~pick_spec & ~pick_dr & (sample1 < c_dt)
            pick_gap = ~pick_sheen & ~pick_spec & ~pick_dr & ~pick_dt & (sample1 < c_all) & (probs[GAP] > 0.0)

            # One visible-normal draw serves sheen and specular (different t, alpha).
            up = mi.Vector3f(0.0, 0.0, 1.0)
            flake_t = dr.select(pick_sheen, up, t)
            flake_alpha = dr.select(pick_sheen, self.sheen_roughness, self.roughness)
            wo_flake, _ = spongecake.sample_specular(wi, flake_t, flake_alpha, sample2)
            wo_diffuse = mi.warp.square_to_cosine_hemisphere(sample2)
            wo_diffuse.z = dr.select(pick_dt, -wo_diffuse.z, wo_diffuse.z)
            wo = dr.select(pick_sheen | pick_spec, wo_flake, wo_diffuse)

            lands_up = wo.z > 0.0
            ok = active & (wi.z > spongecake.COS_EPSILON) & (pick_sheen | pick_spec | pick_dr | pick_dt)
            ok &= ~pick_sheen | lands_up
            ok &= ~pick_spec | dr.select(lands_up, enabled[SPECULAR_REFLECTION], enabled[SPECULAR_TRANSMISSION])

            value, pdf = self._eval_pdf_local(ctx, pt, wo, enabled, probs)
            ok &= pdf > 0.0
            weight = dr.select(ok, value / dr.select(ok, pdf, 1.0), 0.0)

            component = dr.select(pick_sheen, SHEEN,
                        dr.select(pick_spec, dr.select(lands_up, SPECULAR_REFLECTION, SPECULAR_TRANSMISSION),
                        dr.select(pick_dr, DIFFUSE_REFLECTION, DIFFUSE_TRANSMISSION)))

            # Gaps: straight through, a discrete choice of probability probs[GAP].
            gap_ok = active & pick_gap & (wi.z > spongecake.COS_EPSILON)
            gap_weight = pt["t_sheen_i"] * pt["t_sheen_i"] * (1.0 - pt["yarn"]) / dr.select(gap_ok, probs[GAP], 1.0)

            bs = dr.zeros(mi.BSDFSample3f)
            bs.wo = dr.select(gap_ok, -si.wi, self._mirror(pt, wo))
            bs.pdf = dr.select(gap_ok, probs[GAP], dr.select(ok, pdf, 0.0))
            bs.eta = 1.0
            bs.sampled_component = mi.UInt32(dr.select(gap_ok, GAP, component))
            type_of = [mi.UInt32(+f) for f in lobe_types]
            sampled_type = type_of[SHEEN]
            for c in range(1, 6):
                sampled_type = dr.select(bs.sampled_component == c, type_of[c], sampled_type)
            bs.sampled_type = sampled_type
            weight = dr.select(gap_ok, mi.Color3f(gap_weight), weight)
            return bs, weight

        def eval(self, ctx, si, wo, active=True):
            enabled = self._enabled(ctx)
            pt = self._point(ctx, si, active)
            value, _ = self._eval_pdf_local(ctx, pt, self._mirror(pt, wo), enabled, None, want_pdf=False)
            return dr.select(active, value, 0.0)

        def pdf(self, ctx, si, wo, active=True):
            return self.eval_pdf(ctx, si, wo, active)[1]

        def eval_pdf(self, ctx, si, wo, active=True):
            enabled = self._enabled(ctx)
            pt = self._point(ctx, si, active)
            probs = self._lobe_probabilities(ctx, pt, enabled)
            value, pdf = self._eval_pdf_local(ctx, pt, self._mirror(pt, wo), enabled, probs)
            return dr.select(active, value, 0.0), dr.select(active, pdf, 0.0)

        def traverse(self, callback):
            for name in FLOAT_PARAMETERS:
                callback.put(name, getattr(self, name), mi.ParamFlags.NonDifferentiable
                             if name.startswith("uv_scale") else mi.ParamFlags.Differentiable)
            for name in SPECTRUM_PARAMETERS:
                callback.put(name, self.textures[name], mi.ParamFlags.Differentiable)

        def parameters_changed(self, keys=[]):
            pass

        def to_string(self):
            h, w = self.maps.resolution
            return (f"ClothBSDF[pattern={self.pattern!r} ({w}x{h} texels), uv_scale={self.uv_scale}, "
                    f"roughness={self.roughness}, thickness={self.thickness}, "
                    f"sheen_roughness={self.sheen_roughness}, sheen_thickness={self.sheen_thickness}]")

    ClothBSDF.__name__ = "ClothBSDF"
    return ClothBSDF
