"""The ``cloth`` BSDF plugin: wires cloth maps and parameters into the lobes of
supplement Eq. 1. The scattering maths lives in :mod:`mscloth.scattering`, the footprint
(multi-scale) estimator in :mod:`.footprint_estimator`.

Plugin classes bind to the Mitsuba variant active when they are defined, so
:func:`make_cloth_class` builds one class per variant (see :mod:`.registry`).
"""
from __future__ import annotations

import itertools

import drjit as dr
import mitsuba as mi
import numpy as np

from ..jit_arrays import flat_array, gather_block
from ..scattering import sheen, spongecake
from .footprint_data import FootprintData
from .footprint_estimator import FootprintEstimator, edges_in_texels
from .lanes import logical_not
from .lobe_calibration import calibrate
from .lobes import (DIFFUSE_REFLECTION, DIFFUSE_TRANSMISSION, GAP, SHEEN,
                    SPECULAR_REFLECTION, SPECULAR_TRANSMISSION, with_yarn_albedo)
from ..errors import ParameterError
from .parameters import (EXPOSED, FLOAT_PARAMETERS, SPECTRUM_PARAMETERS, _check_float, cloth_maps,
                         exposure_flags, read_parameters, uv_scales, with_flags_column)


#: Numbers cloths that have no id of their own, so that their progress lines differ.
_unnamed_cloths = itertools.count(1)


def cloth_label(plugin_id: str, pattern: str) -> str:
    """``"<id>, <pattern>"``: which cloth a progress line or warning is about.

    The id is the plugin's (``floor.bsdf`` for a cloth nested in shape ``floor`` when loaded
    through :func:`mscloth.loading.load_dict`, which names them); a cloth without one, or
    with Mitsuba's generic ``bsdf``, gets ``cloth <n>``. A pattern given as a path (a maps
    directory, a .wif file) is shown by its last component."""
    name = plugin_id if plugin_id and plugin_id != "bsdf" else f"cloth {next(_unnamed_cloths)}"
    shown = pattern.replace("\\", "/").rstrip("/").rsplit("/", 1)[-1] or pattern
    return f"{name}, {shown}"


from .parameter_docs import DOCSTRING  # noqa: E402  (generated from the parameter table)


def _unzip(pairs):
    """[(a, b), ...] -> ([a, ...], [b, ...])."""
    return [p[0] for p in pairs], [p[1] for p in pairs]


def _max_channel(c):
    return dr.maximum(dr.maximum(c[0], c[1]), c[2])


def _branch(cond, lanes_of, true_fn, false_fn, label):
    """``dr.if_stmt`` on the per-lane ``cond``: a packet whose lanes all take one side skips
    the other's work. In JIT variants ``cond`` is widened to the lanes of ``lanes_of`` first:
    a footprint from constant si.duv_dx/dy (tests, calibration) and the evaluated parameters
    is a single value, and Dr.Jit 1.5.0's if_stmt on a one-value condition that is not a
    literal returns one-value outputs from wider inputs (and then fails to run)."""
    if dr.is_jit_v(mi.Float):
        cond = cond & dr.full(mi.Bool, True, dr.width(lanes_of))
    return dr.if_stmt(args=(), cond=cond, true_fn=true_fn, false_fn=false_fn, label=label)


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
        __doc__ = with_flags_column(DOCSTRING)

        def __init__(self, props):
            # Validate everything before the C++ base is constructed: a base that is
            # constructed (and registered for virtual calls) by an __init__ that then raises
            # leaves a dangling registry entry, and a later render crashes on it.
            p = read_parameters(props)
            maps = cloth_maps(p)
            mi.BSDF.__init__(self, props)
            self.pattern = p.fabric.name if not p.pattern_given else p.pattern
            self.label = cloth_label(props.id(), self.pattern)
            self.maps = maps
            # What the tables and the calibration were built from (parameters_changed
            # builds again when its roughness changes); everything else shading reads live.
            self.build = p.build
            self._pinned = {}
            uv_scale, uv_scale_v = uv_scales(p, maps)
            # uv_scale_v follows uv_scale at the tile's aspect when it was not given.
            self._uv_aspect = None if (p.uv_scale_v and not p.uv_unit) else uv_scale_v / uv_scale
            self.uv_scale = self._parameter("uv_scale", uv_scale)
            self.uv_scale_v = self._parameter("uv_scale_v", uv_scale_v)
            self.roughness = self._parameter("roughness", p.roughness)
            self.thickness = self._parameter("thickness", p.thickness)
            self.sheen_roughness = self._parameter("sheen_roughness", p.sheen_roughness)
            self.sheen_thickness = self._parameter("sheen_thickness", p.sheen_thickness)
            self.textures = p.textures
            self._upload_maps(self.maps)
            self.multiscale = p.build.multiscale
            # Read by clothpath: footprints are shaded whole, so centre them on the pixel.
            self.footprint_shading = p.build.multiscale
            self.use_visibility = p.build.visibility
            self.use_parallax = p.build.parallax
            if p.footprint_slices != 1:
                mi.Log(mi.LogLevel.Warn, f"cloth [{self.label}]: footprint_slices is no longer used: footprints are "
                                         "shaded as the pixel's parallelogram (one probe per sample)")
            flags = 0
            for f in lobe_flags:
                flags |= f
            self.m_components = list(lobe_flags)
            self.m_flags = flags
            self._build_tables()
            self._build_samplers(p.sheen_roughness, p.sheen_thickness)
            self._calibrate(uv_scale, uv_scale_v)

        # ------------------------------------------------------------------
        # What is built from parameters: tables, samplers, calibration
        # ------------------------------------------------------------------
        def _build_tables(self):
            """The multi-scale tables of ``self.build`` (cached: :func:`load_or_build`) in
            Dr.Jit memory, and the footprint estimator that reads them."""
            b = self.build
            self.footprint_data = None
            self.table_key = None
            self.direction_rank = b.direction_rank  # the rank built (see max_table_mib)
            if b.needs_tables:
                from ..precompute.tables import load_or_build

                key, why = b.table_key(*self.maps.resolution)
                self.direction_rank = key.d_rank
                # The rank note comes when the tables are built, not on every cached load.
                note = f"cloth [{self.label}]: {why}" if why and b.multiscale else ""
                tables = load_or_build(self.maps, key, label=self.label, build_warning=note)
                self.table_key = key
                self.footprint_data = FootprintData(tables, with_sats=b.multiscale, with_parallax=b.parallax)
            # The footprint BSDF; before calibration, which samples it.
            self.estimator = FootprintEstimator(self) if b.multiscale else None

        def _build_samplers(self, alpha_s, thickness_s):
            """The samplers of the sheen and the diffuse lobes for the fuzz (``alpha_s``,
            ``thickness_s``) (tables: they carry no gradient, and need none, see
            :data:`EXPOSED`)."""
            # The sheen lobe sampled from a table of itself (JIT variants; scalar variants,
            # for unit tests, reflect on the fuzz's visible normals).
            self.sheen_sampler = sheen.FoldedSheenSampler(self.sheen_roughness)
            with dr.suspend_grad():
                # Diffuse lobes leave through the fuzz: sampled with its transmittance.
                self.diffuse_sampler = sheen.FuzzCosineSampler(alpha_s, thickness_s)
                if dr.is_jit_v(mi.Float) and thickness_s > 0.0:
                    self.sheen_sampler = sheen.TabulatedSheenSampler.shared(alpha_s, thickness_s)

        def _calibrate(self, uv_scale, uv_scale_v):
            """Lobe selection matched to the lobes' albedos, and for footprints to the
            footprint mixture's weights, measured on the BSDF as it is now, at the uv scales
            given (JIT variants; scalar variants, for unit tests, keep the uncalibrated
            proxies)."""
            self.lobe_calibration = None
            self.footprint_calibration = None
            if dr.is_jit_v(mi.Float):
                texel_uv = None
                if self.multiscale:
                    texel_uv = (1.0 / (uv_scale * self.tile_w), 1.0 / (uv_scale_v * self.tile_h))
                with dr.suspend_grad():
                    self.lobe_calibration, self.footprint_calibration = calibrate(self, self.point_proxies, texel_uv)

        def _parameter(self, name, value):
            """A float parameter as an evaluated (opaque) Float in JIT variants, as Mitsuba's
            own plugins hold theirs: two ``cloth`` BSDFs that differ only in parameter
            values then trace the same code, which Dr.Jit runs once for a packet of lanes
            that hit both (one callable instead of two; -4% render time in the demo scene).
            It also keeps Dr.Jit 1.5.0 from folding ``literal 0 * x`` by resizing the
            literal in place (a sheen_thickness of 0 once became as wide as the lanes it
            multiplied); the second reference guards that too."""
            value = mi.Float(value)
            self._pin(name, value)
            return value

        def _pin(self, name, value):
            """Make ``value`` (parameter ``name``'s Float, changed in place by
            ``params.update()``) opaque again, and hold its second reference."""
            if dr.is_jit_v(mi.Float):
                dr.make_opaque(value)
                self._pinned[name] = mi.Float(value)

        def _value(self, name) -> float:
            """Parameter ``name``'s value as a Python float: in JIT variants its float32's
            shortest decimal (0.45, not 0.4499999881), the value a scene would give, so
            that what is built from it (a table's cache key, a shared sheen table) is what a
            scene giving that value builds."""
            if not dr.is_jit_v(mi.Float):
                return float(getattr(self, name))
            return float(str(np.float32(dr.detach(getattr(self, name))[0])))

        def _upload_maps(self, maps):
            fibre = np.concatenate([maps.tangent, maps.gap[..., None]], axis=-1).astype(np.float32)
            color = np.concatenate([maps.albedo, maps.height[..., None]], axis=-1).astype(np.float32)
            # Texel (ix, iy)'s four channels at 4 (iy W + ix): one packet read per texel, at
            # the texel index that the visibility and cluster tables use too (a Texture2f
            # computed its own, and read one channel at a time).
            self.fibre_table = flat_array(fibre)
            self.color_table = flat_array(color)
            self.tile_h, self.tile_w = maps.resolution
            # Uniformly coloured yarns (the common case) need no albedo reads, per texel or
            # from the SATs (a gap texel's colour multiplies nothing: its yarn lobes are 0).
            yarn_colours = maps.albedo[maps.gap > 0]
            self.uniform_yarn_albedo = None
            if len(yarn_colours) and np.all(yarn_colours == yarn_colours[0]):
                self.uniform_yarn_albedo = [float(c) for c in yarn_colours[0]]

        # ------------------------------------------------------------------
        # Shading state: the viewer's frame, a texel (the footprint's: .footprint_estimator)
        # ------------------------------------------------------------------
        def frame(self, si, active):
            """Quantities of the shading point that do not depend on the texel, in the
            mirrored frame where the viewer is above the surface."""
            flip = si.wi.z < 0.0
            sign = dr.select(flip, -1.0, 1.0)
            wi = mi.Vector3f(si.wi.x, si.wi.y, sign * si.wi.z)
            k = {name: self.textures[name].eval(si, active) for name in SPECTRUM_PARAMETERS}
            t_sheen_i = sheen.sheen_transmittance(wi, self.sheen_roughness, self.sheen_thickness)
            # Texel coordinates of si.uv: one tile is tile_w x tile_h texels.
            x = si.uv.x * self.uv_scale * self.tile_w
            y = si.uv.y * self.uv_scale_v * self.tile_h
            if self.use_parallax:
                # Look up (and centre the footprint on) the texel the view ray reaches
                # first in the height field; the table covers the front side only.
                ix, iy = self._texel_index(mi.Point2f(x / self.tile_w, y / self.tile_h))
                dx, dy = self.footprint_data.parallax_offset(ix, iy, wi)
                x = dr.select(flip, x, x + dx)
                y = dr.select(flip, y, y + dy)
            return dict(flip=flip, sign=sign, wi=wi, k=k, t_sheen_i=t_sheen_i, x=x, y=y, active=active)

        def _texel_index(self, pos):
            """The texel (ix, iy) that nearest lookups at tile coordinates ``pos`` read
            (the same wrap as the textures)."""
            ix = mi.UInt32(dr.clip(dr.floor((pos.x - dr.floor(pos.x)) * self.tile_w), 0, self.tile_w - 1))
            iy = mi.UInt32(dr.clip(dr.floor((pos.y - dr.floor(pos.y)) * self.tile_h), 0, self.tile_h - 1))
            return ix, iy

        def texel(self, fr, x, y):
            """The point (fibre-level) state at texel coordinates (x, y) (periodic)."""
            pos = mi.Point2f(x / self.tile_w, y / self.tile_h)
            ix, iy = self._texel_index(pos)
            start = (iy * self.tile_w + ix) * 4
            fibre = gather_block(self.fibre_table, start, 4, fr["active"])
            if self.uniform_yarn_albedo is not None:
                color = mi.Color3f(*self.uniform_yarn_albedo)
            else:
                color = mi.Color3f(*gather_block(self.color_table, start, 4, fr["active"])[:3])
            tangent = mi.Vector3f(fibre[0], fibre[1], fr["sign"] * fibre[2])
            k = with_yarn_albedo(fr["k"], color)
            return dict(fr, tangent=tangent, yarn=fibre[3], k=k, ix=ix, iy=iy)

        def _half_widths_texels(self, si):
            """Half-widths in texels of this tile of the footprint in si.duv_dx/dy."""
            (ax, ay), (bx, by) = edges_in_texels(self, si)
            return 0.5 * (dr.abs(ax) + dr.abs(bx)), 0.5 * (dr.abs(ay) + dr.abs(by))

        def enabled(self, ctx):
            """Whether each of the six lobes is enabled by ``ctx`` (its type mask, component)."""
            return [ctx.is_enabled(lobe_types[c], c) for c in range(6)]

        def _lobe_probabilities(self, pt, enabled):
            """Selection probabilities of the texel's lobes, proportional to each lobe's
            estimated albedo."""
            return self.lobe_weights(pt["k"], pt["wi"], pt["yarn"], pt["t_sheen_i"], self._scattered(pt), enabled,
                                      self.lobe_calibration)

        def _scattered(self, pt):
            """The share of light the texel's specular slab scatters (for its proxy)."""
            return 1.0 - spongecake.unscattered_transmittance(pt["wi"], pt["tangent"], self.roughness, self.thickness)

        def point_proxies(self, si):
            """Unnormalised lobe proxies of the fibre-level texels of ``si`` (calibration)."""
            fr = self.frame(si, True)
            pt = self.texel(fr, fr["x"], fr["y"])
            return self._lobe_proxies(pt["k"], pt["wi"], pt["yarn"], pt["t_sheen_i"], self._scattered(pt), [True] * 6)

        def lobe_weights(self, k, wi, yarn, ts, scattered, enabled, calibration):
            """Normalised lobe probabilities for yarn coverage ``yarn``, lobe albedos ``k``
            (yarn colour included) and scattered fraction ``scattered``: the proxies times
            ``calibration``'s ratios (:mod:`.lobe_calibration`; None: the raw proxies)."""
            w = self._lobe_proxies(k, wi, yarn, ts, scattered, enabled)
            if calibration is not None:
                w = calibration.scale(w, wi.z)
            total = w[0] + w[1] + w[2] + w[3] + w[4] + w[5]
            inv = dr.select(total > 0.0, dr.rcp(total), 0.0)
            return [wk * inv for wk in w]

        def _lobe_proxies(self, k, wi, yarn, ts, scattered, enabled):
            """Cheap unnormalised albedo estimates of the six lobes (the gap's is exact)."""
            zero = dr.zeros(mi.Float, dr.width(wi))
            w = [zero] * 6
            if enabled[SHEEN]:
                w[SHEEN] = _max_channel(k["sheen_color"]) * (1.0 - ts)
            spec = zero
            if enabled[SPECULAR_REFLECTION]:
                spec = _max_channel(k["specular_albedo"])
            if enabled[SPECULAR_TRANSMISSION]:
                spec = dr.maximum(spec, _max_channel(k["specular_transmittance"]))
            w[SPECULAR_REFLECTION] = ts * yarn * spec * scattered
            if enabled[DIFFUSE_REFLECTION]:
                w[DIFFUSE_REFLECTION] = ts * yarn * _max_channel(k["diffuse_albedo"])
            if enabled[DIFFUSE_TRANSMISSION]:
                w[DIFFUSE_TRANSMISSION] = ts * yarn * _max_channel(k["diffuse_transmittance"])
            if enabled[GAP]:
                w[GAP] = ts * ts * (1.0 - yarn)
            return w

        @staticmethod
        def _outgoing_side(flip, wo):
            """(wo folded up, back?) for the visibility tables: the outgoing direction
            (mirrored frame) sees the viewer's side for reflection, the other side for
            transmission."""
            return mi.Vector3f(wo.x, wo.y, dr.abs(wo.z)), flip == (wo.z > 0.0)

        def visibility_o(self, pt, wo):
            """V(p, o) of the texel for the outgoing direction (mirrored frame), from its
            visibility bits ``pt["vis"]``."""
            wo_up, back = self._outgoing_side(pt["flip"], wo)
            return self.footprint_data.visibility_of(pt["vis"], wo_up, back)

        def _visibility(self, pt, wo):
            """V(p, i, o) of the texel: shadowing x masking by the cloth's height field.
            The viewer's side uses the front table, mirrored when the viewer is below."""
            if self.footprint_data is None:
                return mi.Float(1.0)
            v_i = self.footprint_data.visibility_of(pt["vis"], pt["wi"], pt["flip"])
            return v_i * self.visibility_o(pt, wo)

        def cluster_visibilities_o(self, fr, wo):
            """Every cluster's mean V for the outgoing direction (mirrored frame)."""
            return self.footprint_data.cluster_visibilities(*self._outgoing_side(fr["flip"], wo))

        def sheen_and_fuzz(self, fr, wo, enabled):
            """(f_sheen |cos o| k_sheen, T_sheen(i) T_sheen(o)) for the outgoing direction
            (mirrored frame): the fuzz's reflection and what crosses it both ways; the
            second comes with the first's exponentials when the sheen is evaluated."""
            if enabled[SHEEN]:
                f_sheen, fuzz = sheen.eval_sheen_transmittance(fr["wi"], wo, self.sheen_roughness,
                                                               self.sheen_thickness)
                return f_sheen * fr["k"]["sheen_color"], fuzz
            fuzz = fr["t_sheen_i"] * sheen.sheen_transmittance(wo, self.sheen_roughness, self.sheen_thickness)
            return mi.Color3f(0.0), fuzz

        def _eval_pdf_point(self, pt, wo, enabled, probs):
            """Fibre-level (one texel) non-delta f*|cos o| and pdf, mirrored frame."""
            wi, t, yarn, k = pt["wi"], pt["tangent"], pt["yarn"], pt["k"]
            cos_o = wo.z
            up = cos_o > 0.0
            valid = (wi.z > spongecake.COS_EPSILON) & (dr.abs(cos_o) > spongecake.COS_EPSILON)
            value, fuzz = self.sheen_and_fuzz(pt, wo, enabled)
            under_fuzz = fuzz * yarn
            reflection = mi.Color3f(0.0)
            transmission = mi.Color3f(0.0)
            if enabled[SPECULAR_REFLECTION] or enabled[SPECULAR_TRANSMISSION]:
                spec, _ = spongecake.eval_specular(wi, wo, t, self.roughness, self.thickness)
                if enabled[SPECULAR_REFLECTION]:
                    reflection += k["specular_albedo"] * spec
                if enabled[SPECULAR_TRANSMISSION]:
                    transmission += k["specular_transmittance"] * spec
            cosine = dr.abs(cos_o) * dr.inv_pi
            if enabled[DIFFUSE_REFLECTION]:
                reflection += k["diffuse_albedo"] * cosine
            if enabled[DIFFUSE_TRANSMISSION]:
                transmission += k["diffuse_transmittance"] * cosine
            yarn_lobes = dr.select(up, reflection, transmission)
            if self.use_visibility:
                yarn_lobes *= self._visibility(pt, wo)
            value += under_fuzz * yarn_lobes
            value = dr.select(valid, value, 0.0)
            pdf = dr.select(valid, self.lobes_pdf(wi, wo, probs, [t], enabled), 0.0)
            return value, pdf

        def lobes_pdf(self, wi, wo, probs, tangents, enabled):
            """Density of picking a lobe by ``probs`` and sampling it (mirrored frame), the
            specular lobe from one of ``tangents`` chosen uniformly; validity not masked."""
            up = wo.z > 0.0
            pdf = mi.Float(0.0)
            if enabled[SHEEN]:
                pdf += probs[SHEEN] * self.sheen_sampler.pdf(wi, wo)
            if enabled[SPECULAR_REFLECTION] or enabled[SPECULAR_TRANSMISSION]:
                side_ok = (up & enabled[SPECULAR_REFLECTION]) | (logical_not(up) & enabled[SPECULAR_TRANSMISSION])
                spec = mi.Float(0.0)
                for t in tangents:
                    spec += spongecake.pdf_specular(wi, wo, t, self.roughness)
                pdf += probs[SPECULAR_REFLECTION] * dr.select(side_ok, spec * (1.0 / len(tangents)), 0.0)
            if enabled[DIFFUSE_REFLECTION] or enabled[DIFFUSE_TRANSMISSION]:
                diffuse = self.diffuse_sampler.pdf(wo)
                if enabled[DIFFUSE_REFLECTION]:
                    pdf += probs[DIFFUSE_REFLECTION] * dr.select(up, diffuse, 0.0)
                if enabled[DIFFUSE_TRANSMISSION]:
                    pdf += probs[DIFFUSE_TRANSMISSION] * dr.select(up, 0.0, diffuse)
            return pdf

        def mirror(self, fr, wo):
            """``wo`` in the mirrored frame of ``fr`` (where the viewer is above), or back."""
            return mi.Vector3f(wo.x, wo.y, fr["sign"] * wo.z)

        def sample_point(self, pt, probs, enabled, sample1, sample2, active):
            """Fibre-level sampling at one texel: (wo, ok, component, pick_gap)."""
            wi, t = pt["wi"], pt["tangent"]
            c_sheen = probs[SHEEN]
            c_spec = c_sheen + probs[SPECULAR_REFLECTION]
            c_dr = c_spec + probs[DIFFUSE_REFLECTION]
            c_dt = c_dr + probs[DIFFUSE_TRANSMISSION]
            c_all = c_dt + probs[GAP]
            pick_sheen = sample1 < c_sheen
            pick_spec = logical_not(pick_sheen) & (sample1 < c_spec)
            pick_dr = logical_not(pick_sheen) & logical_not(pick_spec) & (sample1 < c_dr)
            pick_dt = logical_not(pick_sheen) & logical_not(pick_spec) & logical_not(pick_dr) & (sample1 < c_dt)
            pick_gap = (logical_not(pick_sheen) & logical_not(pick_spec) & logical_not(pick_dr) & logical_not(pick_dt)
                        & (sample1 < c_all) & (probs[GAP] > 0.0))

            wo_spec, _ = spongecake.sample_specular(wi, t, self.roughness, sample2)
            wo_sheen = wo_spec
            if enabled[SHEEN]:
                wo_sheen, _ = self.sheen_sampler.sample(wi, sample2)
            wo_diffuse = self.diffuse_sampler.sample(sample2)
            wo_diffuse.z = dr.select(pick_dt, -wo_diffuse.z, wo_diffuse.z)
            wo = dr.select(pick_sheen, wo_sheen, dr.select(pick_spec, wo_spec, wo_diffuse))

            lands_up = wo.z > 0.0
            ok = active & (wi.z > spongecake.COS_EPSILON) & (pick_sheen | pick_spec | pick_dr | pick_dt)
            ok &= logical_not(pick_sheen) | lands_up
            ok &= logical_not(pick_spec) | dr.select(lands_up, enabled[SPECULAR_REFLECTION],
                                                     enabled[SPECULAR_TRANSMISSION])
            component = dr.select(pick_sheen, SHEEN,
                        dr.select(pick_spec, dr.select(lands_up, SPECULAR_REFLECTION, SPECULAR_TRANSMISSION),
                        dr.select(pick_dr, DIFFUSE_REFLECTION, DIFFUSE_TRANSMISSION)))
            gap_ok = active & pick_gap & (wi.z > spongecake.COS_EPSILON)
            return wo, ok, mi.UInt32(component), gap_ok

        # ------------------------------------------------------------------
        # Shared by the mi.BSDF methods
        # ------------------------------------------------------------------
        def _point_branch(self, si, fr, enabled, wos, samples, active, fp=None, xi=None):
            """(values, pdfs, sample record) of the fibre-level BSDF at the texel under
            si.uv (or, for a small footprint ``fp``, under the point ``xi`` of it, uniform in
            [0,1)^2: the shading hash's), for the mirrored directions ``wos`` and, if given,
            one sample."""
            x, y = fr["x"], fr["y"]
            if fp is not None:
                offset = fr.get("pixel_offset")
                if offset is not None:
                    # The sample's own point of the pixel: brute force, exactly.
                    known = (offset.x >= -0.5) & (offset.y >= -0.5)
                    xi = dr.select(known, mi.Point2f(offset.x + 0.5, offset.y + 0.5), xi)
                x, y = self.estimator.point_in_footprint(fr, fp, xi)
            pt = self.texel(fr, x, y)
            if self.use_visibility and self.footprint_data is not None:
                # The texel's visibility bits, read once for every direction below.
                pt["vis"] = self.footprint_data.texel_visibility(pt["ix"], pt["iy"])
            probs = self._lobe_probabilities(pt, enabled)

            def eval_pdf(wo):
                return self._eval_pdf_point(pt, wo, enabled, probs)

            record = ()
            if samples is not None:
                wo, ok, component, gap_ok = self.sample_point(pt, probs, enabled, *samples, active)
                gap_value = fr["t_sheen_i"] * fr["t_sheen_i"] * (1.0 - pt["yarn"])
                record = self._sample_record(si, fr, eval_pdf, wo, ok, component, gap_ok, probs[GAP], gap_value)
            values, pdfs = _unzip([eval_pdf(wo) for wo in wos])
            return values, pdfs, record

        def _footprint_branch(self, si, fr, enabled, wos, samples, active, fp, hashed):
            """The same for the footprint BSDF (multi-scale shading) of footprint ``fp``,
            with the shading hash ``hashed`` it came from."""
            estimator = self.estimator
            xi, xi_round, _ = hashed
            st = estimator.state(si, fr, enabled, xi, xi_round, fp=fp)

            def eval_pdf(wo):
                return estimator.eval(fr, st, wo, enabled), estimator.pdf(fr, st, wo, enabled)

            record = ()
            if samples is not None:
                record = self._sample_record(si, fr, eval_pdf, *estimator.sample(fr, st, enabled, *samples, active))
            values, pdfs = _unzip([eval_pdf(wo) for wo in wos])
            return values, pdfs, record

        def _sample_record(self, si, fr, eval_pdf, wo, ok, component, gap_ok, gap_pdf, gap_value):
            """(wo in the world's local frame, pdf, component, weight) of a sampled
            mirrored direction, or of the gap."""
            value, pdf = eval_pdf(wo)
            ok &= pdf > 0.0
            weight = dr.select(ok, value / dr.select(ok, pdf, 1.0), 0.0)
            gap_ok &= gap_pdf > 0.0
            gap_weight = gap_value / dr.select(gap_ok, gap_pdf, 1.0)
            return (dr.select(gap_ok, -si.wi, self.mirror(fr, wo)),
                    dr.select(gap_ok, gap_pdf, dr.select(ok, pdf, 0.0)),
                    dr.select(gap_ok, mi.UInt32(GAP), component),
                    dr.select(gap_ok, mi.Color3f(gap_weight), weight))

        def _bsdf_sample(self, record):
            """(BSDFSample3f, weight) of a sample record. Built after the branches: values
            that are the same literal in both branches of a symbolic if (eta = 1) trip
            Dr.Jit's LLVM code generation inside virtual calls."""
            wo, pdf, component, weight = record
            bs = dr.zeros(mi.BSDFSample3f)
            bs.wo = wo
            bs.pdf = pdf
            bs.eta = 1.0
            bs.sampled_component = component
            type_of = [mi.UInt32(+f) for f in lobe_types]
            sampled_type = type_of[SHEEN]
            for c in range(1, 6):
                sampled_type = dr.select(component == c, type_of[c], sampled_type)
            bs.sampled_type = sampled_type
            return bs, weight

        def _shade(self, ctx, si, wos, samples, active, pixel_offset=None):
            """eval_pdf at the world-frame directions ``wos`` and, if ``samples`` =
            (sample1, sample2) is given, one sample: ([values], [pdfs], (bs, weight) or ()).
            ``pixel_offset``: the sample's offset from its pixel's centre, in pixels along
            the footprint's edges si.duv_dx, si.duv_dy (each in [-1/2, 1/2); below: not
            known), which picks its probe (``estimator.footprint``) and fibre-level point.

            Footprints of a texel or more take the multi-scale branch, smaller ones the
            fibre-level one; a symbolic if, so a packet of lanes that all take one branch
            skips the other's work."""
            enabled = self.enabled(ctx)
            fr = self.frame(si, active)
            fr["pixel_offset"] = pixel_offset
            wos = [self.mirror(fr, wo) for wo in wos]
            if not self.multiscale:
                values, pdfs, record = self._point_branch(si, fr, enabled, wos, samples, active)
            else:
                # One hash and one footprint per shading point, for the branch choice and
                # for the branch taken.
                hashed = self.estimator.shading_hash(si)
                fp = self.estimator.footprint(si, fr, hashed[2])
                values, pdfs, record = _branch(
                    fp.use, (si, wos, samples),
                    true_fn=lambda: self._footprint_branch(si, fr, enabled, wos, samples, active, fp, hashed),
                    false_fn=lambda: self._point_branch(si, fr, enabled, wos, samples, active, fp, hashed[0]),
                    label="cloth_footprint")
            values = [dr.select(active, v, 0.0) for v in values]
            pdfs = [dr.select(active, p, 0.0) for p in pdfs]
            return values, pdfs, (self._bsdf_sample(record) if record else ())

        # ------------------------------------------------------------------
        # mi.BSDF interface
        # ------------------------------------------------------------------
        def sample(self, ctx, si, sample1, sample2, active=True):
            return self._shade(ctx, si, [], (sample1, sample2), active)[2]

        def eval_pdf(self, ctx, si, wo, active=True):
            values, pdfs, _ = self._shade(ctx, si, [wo], None, active)
            return values[0], pdfs[0]

        def eval(self, ctx, si, wo, active=True):
            return self.eval_pdf(ctx, si, wo, active)[0]

        def footprint_texels(self, si, active=True):
            """Full widths (u, v) in texels of this tile of the footprint in si.duv_dx/dy
            (the ``footprint_texels_*`` AOVs of clothpath)."""
            rx, ry = self._half_widths_texels(si)
            wu, wv = 2.0 * rx, 2.0 * ry
            ok = active & dr.isfinite(wu) & dr.isfinite(wv)
            return dr.select(ok, wu, 0.0), dr.select(ok, wv, 0.0)

        def gap_transmission(self, si, active=True):
            """Fraction of light crossing the cloth straight along -si.wi through its gaps:
            T_sheen(i)^2 (1 - I), with I the yarn coverage of the footprint in
            si.duv_dx/dy (multi-scale; below 8 texels, possibly of the texel at the point
            fibre-level shading takes) or of the texel (used by clothpath's shadow rays).
            The footprint's I is its mean over the stochastically rounded box, the one the
            footprint BSDF shades: the crossing lets through what the BSDF's gap lobe
            does at the same point."""
            fr = self.frame(si, active)

            if not self.multiscale:
                yarn = self.texel(fr, fr["x"], fr["y"])["yarn"]
            else:
                estimator = self.estimator
                xi, xi_round, u = estimator.shading_hash(si)
                fp = estimator.footprint(si, fr, u)
                sats = self.footprint_data.scalar_sats

                def texel_yarn():  # at the point the fibre-level branch shades
                    return self.texel(fr, *estimator.point_in_footprint(fr, fp, xi))["yarn"]

                def footprint_yarn():
                    # One read per corner of the rounded box (exact corners took four, and
                    # were most of what a shadow ray crossing cloth cost). Its mean stays in
                    # [0, 1]: over the exact area it did not, and the clip below then let
                    # light through gap-free footprints (docs/decisions.md).
                    _, q = estimator.rounded_box(fp, xi_round)
                    return sats.integral(q, self.footprint_data.GAP) / q.area

                # Packets whose lanes all have a footprint skip the texel read; packets
                # without one (shadow rays from vertices shaded at a point) the table reads.
                yarn = _branch(fp.use & active, (si, active), true_fn=footprint_yarn,
                               false_fn=texel_yarn, label="cloth_gap_footprint")
            t_sheen = fr["t_sheen_i"]
            return dr.select(active & (dr.abs(si.wi.z) > spongecake.COS_EPSILON),
                             t_sheen * t_sheen * dr.clip(1.0 - yarn, 0.0, 1.0), 0.0)

        def pdf(self, ctx, si, wo, active=True):
            return self.eval_pdf(ctx, si, wo, active)[1]

        def eval_pdf_sample_n(self, ctx, si, wos, sample1, sample2, active=True, pixel_offset=None):
            """eval_pdf at every direction of ``wos`` and one sample, sharing one footprint
            state (SAT means, visibilities, the sampling mixture: all independent of the
            outgoing direction). Called by ``clothpath`` through ``dr.dispatch``, which
            passes the camera sample's ``pixel_offset`` at first hits (see ``_shade``)."""
            values, pdfs, (bs, weight) = self._shade(ctx, si, wos, (sample1, sample2), active, pixel_offset)
            return values, pdfs, bs, weight

        def eval_pdf_sample(self, ctx, si, wo, sample1, sample2, active=True):
            values, pdfs, bs, weight = self.eval_pdf_sample_n(ctx, si, [wo], sample1, sample2, active)
            return values[0], pdfs[0], bs, weight

        def traverse(self, callback):
            # Flags from parameters.EXPOSED: differentiable where eval reads the value live.
            for name in EXPOSED:
                value = self.textures[name] if name in self.textures else getattr(self, name)
                callback.put(name, value, exposure_flags(name, self.multiscale))

        def parameters_changed(self, keys=[]):
            """After ``params.update()``: every changed float is checked and made opaque
            again; a changed fuzz rebuilds the samplers; a changed roughness rebuilds what
            was built from it (the tables where shading reads them, then the calibration),
            as a BSDF loaded with it would have. Other parameters are read live. No keys:
            all of them may have changed (Mitsuba's convention)."""
            changed = set(keys) if keys else set(EXPOSED)
            where = f"cloth [{self.label}]"
            for name in FLOAT_PARAMETERS:
                if name in changed and name in EXPOSED:
                    _check_float(name, self._value(name), where)
                    self._pin(name, getattr(self, name))
            if "uv_scale_v" in changed and keys:
                self._uv_aspect = None  # given now
            elif "uv_scale" in changed and self._uv_aspect is not None:
                # A v scale derived from uv_scale (and the tile's aspect) stays so, as when loaded.
                v = self._value("uv_scale") * self._uv_aspect
                if dr.is_jit_v(mi.Float):
                    mi.set_property(self.uv_scale_v, mi.Float(v))  # in place: params holds it
                else:
                    self.uv_scale_v = v
                self._pin("uv_scale_v", self.uv_scale_v)
            if changed & {"sheen_roughness", "sheen_thickness"}:
                self._build_samplers(self._value("sheen_roughness"), self._value("sheen_thickness"))
            roughness = self._value("roughness")
            if "roughness" in changed and np.float32(roughness) != np.float32(self.build.roughness):
                try:
                    build = self.build.with_roughness(roughness)
                except ParameterError as error:
                    reason = str(error).removeprefix("cloth: ")
                    raise ParameterError(f"{where}: roughness {roughness:g} does not fit the tables: {reason}; "
                                         "reload the scene with other direction_bins or direction_rank") from None
                tables_change = self.build.tables_read_roughness
                self.build = build
                if tables_change:
                    self._build_tables()
                self._calibrate(self._value("uv_scale"), self._value("uv_scale_v"))

        def to_string(self):
            h, w = self.maps.resolution
            return (f"ClothBSDF[pattern={self.pattern!r} ({w}x{h} texels), uv_scale={self.uv_scale}, "
                    f"roughness={self.roughness}, thickness={self.thickness}, "
                    f"sheen_roughness={self.sheen_roughness}, sheen_thickness={self.sheen_thickness}]")

    ClothBSDF.__name__ = "ClothBSDF"
    return ClothBSDF
