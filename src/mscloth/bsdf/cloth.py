"""The ``cloth`` BSDF plugin: wires cloth maps and parameters into the lobes of
supplement Eq. 1. The scattering maths lives in :mod:`mscloth.scattering`.

Plugin classes bind to the Mitsuba variant active when they are defined, so
:func:`make_cloth_class` builds one class per variant (see :mod:`.registry`).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..jit_arrays import flat_array, gather_block
from ..maps.builtin import resolve_pattern
from ..scattering import sggx, sheen, spongecake
from .footprint_data import FootprintData
from .lobe_calibration import calibrate
from .lobes import (DIFFUSE_REFLECTION, DIFFUSE_TRANSMISSION, GAP, SHEEN,
                    SPECULAR_REFLECTION, SPECULAR_TRANSMISSION)
from .sat_queries import hemisphere_bins, round_box
from .parameters import FLOAT_PARAMETERS, SPECTRUM_PARAMETERS, read_parameters


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
   * - multiscale
     - boolean
     - true
     - Shade whole pixel footprints (summed-area tables + CCV); needs an integrator
       that sets ``si.duv_dx/dy`` such as ``clothpath``.
   * - visibility
     - boolean
     - true
     - Shadowing x masking by the cloth's height field.
   * - unbiased_ccv
     - boolean
     - false
     - Per-cluster control-variate base: each residual texel's control variate takes its
       own cluster's visibility (less noise below a tile), for 8x the directional SAT
       memory and about twice the shading time. Both bases are unbiased: the default one
       weighs each cluster by its share of the footprint's D, and its control variate takes
       that mean visibility (``docs/decisions.md``).
   * - parallax
     - boolean
     - false
     - Shift lookups to where the view ray meets the height field (Alg. 3); makes
       the BSDF non-reciprocal, hence off by default.
   * - direction_bins
     - integer
     - 0
     - Half-vector bins per side of the directional SAT; 0: from the roughness (16 at 0.2
       and above, 32 down to 0.08, 48 below), fine enough for the fibres' lobe.
   * - visibility_bins, clusters
     - integer
     - 8, 8
     - Table sizes of the height-field visibility and its control variates.
   * - direction_rank
     - integer
     - 0
     - Rank K of the compressed directional SAT (0: full, direction_bins^2 channels, unless
       that exceeds ``max_table_mib``): K channels and a bins x K basis (PCA of D over the
       tile); 64 keeps footprint means within ~0.5% at roughness 0.3 and cuts a 512^2,
       dr = 32 table from 1 GiB to 64 MiB, at about twice the time per sample.
   * - max_table_mib
     - integer
     - 256
     - Memory budget in MiB of the full directional SAT (``direction_rank`` 0). A tile whose
       full table would be larger gets rank 64 instead (or the largest rank that fits),
       with a warning: e.g. 512^2 texels at 32^2 bins (1 GiB). Raise it to keep the full
       table, which is faster per sample.
   * - footprint_slices
     - integer
     - 1
     - No longer used (accepted, with a warning, for older scenes): a footprint is the
       pixel's parallelogram, shaded one probe per sample along its longer edge.

Multi-scale shading takes the pixel footprint as the parallelogram spanned by
``si.duv_dx`` and ``si.duv_dy`` around ``si.uv``: cut along one edge into at most 8 slices
(those whose bounding boxes cover least area; one for an axis-aligned rectangle), one slice
per sample shaded whole as its bounding box. Footprints under 2 texels are shaded fibre level at a point drawn in the
parallelogram, those over 8 texels whole, and those between by one or the other, with a
weight linear in the area. Direction bins of the tables are read with their bilinear
weights.

Sampling picks one lobe by an estimate of its albedo, calibrated when the BSDF is built
against measured lobe albedos (``bsdf/lobe_calibration.py``; JIT variants), and samples it
exactly (visible normals, cosine); the weight is the whole mixture's eval over its pdf.

Per channel, diffuse_albedo + diffuse_transmittance + max(specular_albedo,
specular_transmittance) must not exceed 1, so that no configuration creates
energy. Components (for ``BSDFContext.component``): 0 sheen, 1 specular
reflection, 2 diffuse reflection, 3 specular transmission, 4 diffuse
transmission, 5 gap (delta transmission).
"""


def _with_yarn_albedo(k, yarn_albedo):
    """The lobe albedos with the yarn colour applied (every yarn lobe; not sheen)."""
    k = dict(k)
    for name in ("specular_albedo", "specular_transmittance", "diffuse_albedo", "diffuse_transmittance"):
        k[name] = k[name] * yarn_albedo
    return k


def _unzip(pairs):
    """[(a, b), ...] -> ([a, ...], [b, ...])."""
    return [p[0] for p in pairs], [p[1] for p in pairs]


def _not(mask):
    """Logical not, also for the Python bools of scalar variants (where ~ gives an int)."""
    return mask ^ True


def _pick(values, index):
    """values[index] per lane, for a short Python list of per-lane values."""
    out = values[0]
    for c in range(1, len(values)):
        out = dr.select(index == c, values[c], out)
    return out


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
            self._pinned = []
            self.uv_scale = self._parameter(p.uv_scale)
            # Square UV units see the tile at its physical aspect unless told otherwise.
            width_mm, height_mm = self.maps.meta.get("tile_size_mm", (1.0, 1.0))
            uv_scale_v = p.uv_scale_v or p.uv_scale * width_mm / height_mm
            self.uv_scale_v = self._parameter(uv_scale_v)
            self.roughness = self._parameter(p.roughness)
            self.thickness = self._parameter(p.thickness)
            self.sheen_roughness = self._parameter(p.sheen_roughness)
            self.sheen_thickness = self._parameter(p.sheen_thickness)
            self.textures = p.textures
            self._upload_maps(self.maps)
            self.multiscale = p.multiscale
            # Read by clothpath: footprints are shaded whole, so centre them on the pixel.
            self.footprint_shading = p.multiscale
            self.use_visibility = p.visibility
            self.use_parallax = p.parallax
            if p.footprint_slices != 1:
                mi.Log(mi.LogLevel.Warn, f"cloth ({p.pattern}): footprint_slices is no longer used: footprints are "
                                         "shaded as the pixel's parallelogram (one probe per sample)")
            self.footprint_data = None
            self.direction_rank = p.direction_rank  # the rank built (see max_table_mib)
            if p.multiscale or p.visibility or p.parallax:
                from ..precompute.tables import choose_direction_rank, load_or_build

                rank, why = choose_direction_rank(*self.maps.resolution, p.direction_bins, p.direction_rank,
                                                  p.max_table_mib)
                if why and p.multiscale:
                    mi.Log(mi.LogLevel.Warn, f"cloth ({p.pattern}): {why}")
                self.direction_rank = rank
                tables = load_or_build(self.maps, p.roughness, dr=p.direction_bins, dv=p.visibility_bins,
                                       clusters=p.clusters, per_cluster_sat=p.unbiased_ccv,
                                       d_rank=rank, parallax=p.parallax)
                self.footprint_data = FootprintData(tables, with_sats=p.multiscale, with_parallax=p.parallax)

            flags = 0
            for f in lobe_flags:
                flags |= f
            self.m_components = list(lobe_flags)
            self.m_flags = flags
            # The sheen lobe sampled from a table of itself (JIT variants; scalar variants,
            # for unit tests, reflect on the fuzz's visible normals).
            self.sheen_sampler = sheen.FoldedSheenSampler(self.sheen_roughness)
            # Diffuse lobes leave through the fuzz: sampled with its transmittance.
            with dr.suspend_grad():
                self.diffuse_sampler = sheen.FuzzCosineSampler(p.sheen_roughness, p.sheen_thickness)
            if dr.is_jit_v(mi.Float) and p.sheen_thickness > 0.0:
                with dr.suspend_grad():
                    self.sheen_sampler = sheen.TabulatedSheenSampler.shared(p.sheen_roughness, p.sheen_thickness)
            # Lobe selection matched to the lobes' albedos, and for footprints to the
            # footprint mixture's weights, measured once (JIT variants; scalar variants, for
            # unit tests, keep the uncalibrated proxies).
            self.lobe_calibration = None
            self.footprint_calibration = None
            if dr.is_jit_v(mi.Float):
                texel_uv = None
                if self.multiscale:
                    texel_uv = (1.0 / (p.uv_scale * self.tile_w), 1.0 / (uv_scale_v * self.tile_h))
                with dr.suspend_grad():
                    self.lobe_calibration, self.footprint_calibration = calibrate(self, self._point_proxies, texel_uv)

        def _parameter(self, value):
            """A float parameter as an evaluated (opaque) Float in JIT variants, as Mitsuba's
            own plugins hold theirs: two ``cloth`` BSDFs that differ only in parameter
            values then trace the same code, which Dr.Jit runs once for a packet of lanes
            that hit both (one callable instead of two; -4% render time in the demo scene).
            It also keeps Dr.Jit 1.5.0 from folding ``literal 0 * x`` by resizing the
            literal in place (a sheen_thickness of 0 once became as wide as the lanes it
            multiplied); the second reference guards that too."""
            value = mi.Float(value)
            if dr.is_jit_v(mi.Float):
                dr.make_opaque(value)
                self._pinned.append(mi.Float(value))
            return value

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
        # Shading state: the viewer's frame, a texel, a footprint
        # ------------------------------------------------------------------
        def _frame(self, si, active):
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

        def _texel(self, fr, x, y):
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
            k = _with_yarn_albedo(fr["k"], color)
            return dict(fr, tangent=tangent, yarn=fibre[3], k=k, ix=ix, iy=iy)

        def _footprint(self, si, fr, u, u_probe=None):
            """The pixel footprint's probe (a texel box), and whether to shade it as one.

            Convention (docs/decisions.md): the footprint is the parallelogram spanned by
            si.duv_dx and si.duv_dy, centred on si.uv. It is cut along one edge into the n
            slices (n <= ``MAX_PROBES``) whose bounding boxes cover the least area (one for
            an axis-aligned rectangle; the edge that does better), and one slice,
            picked by ``u``, is shaded as its axis-aligned bounding box (the probe): as
            hardware anisotropic filtering does, with the probes taken one per sample. The
            expected probe is the parallelogram, not its bounding box, at one box's reads.

            Footprints covering fewer than ``POINT_TEXELS`` texels are shaded fibre level at
            a point drawn uniformly in the parallelogram (exactly the fibre-level BSDF at
            si.uv for a zero footprint), those over ``FOOTPRINT_TEXELS`` whole, and those
            between by one or the other, picked by ``u`` with a weight linear in the
            area: both estimate the same footprint mean, and a footprint of a few texels
            was noisier than a fibre-level sample. ``u_probe`` (default: ``u`` rescaled
            within the footprint's share) picks the probe.
            """
            (ax, ay), (bx, by) = self._edges_texels(si)
            finite = dr.isfinite(ax) & dr.isfinite(ay) & dr.isfinite(bx) & dr.isfinite(by)
            la2, lb2 = ax * ax + ay * ay, bx * bx + by * by
            area = dr.abs(ax * by - ay * bx)
            length = dr.safe_sqrt(dr.maximum(la2, lb2))
            # Width across the long edge; a degenerate (line) footprint covers a texel's width.
            width = area * dr.select(length > 0.0, dr.rcp(length), 0.0)
            texels = dr.maximum(length, 1.0) * dr.maximum(width, 1.0)
            p_use = dr.clip((texels - self.POINT_TEXELS) * (1.0 / (self.FOOTPRINT_TEXELS - self.POINT_TEXELS)),
                            0.0, 1.0)
            p_use = dr.select(finite & (length > 0.0), p_use, 0.0)
            # (p_use > 0) first: a zero footprint of constant si.duv_dx/dy is then a literal
            # False, and the symbolic if traces the fibre-level branch alone.
            use = (p_use > 0.0) & (u < p_use)
            if u_probe is None:
                u_probe = dr.minimum(u * dr.select(p_use > 0.0, dr.rcp(p_use), 0.0), 0.99999994)
                u_probe_a = u_probe_b = u_probe
                offset = fr.get("pixel_offset")
                if offset is not None:
                    # The slice the sample lies in: with a stratified sampler (multijitter
                    # stratifies each pixel axis), a pixel's samples spread evenly over
                    # its slices, and the probes' variance between them mostly cancels.
                    known = (offset.x >= -0.5) & (offset.y >= -0.5)
                    u_probe_a = dr.select(known, dr.clip(offset.x + 0.5, 0.0, 0.99999994), u_probe)
                    u_probe_b = dr.select(known, dr.clip(offset.y + 0.5, 0.0, 0.99999994), u_probe)
            else:
                u_probe_a = u_probe_b = u_probe

            def slicing(l_x, l_y, l2, s_x, s_y):
                """(n, the n slices' bounding-box area) cutting edge l into n slices: the n
                that minimises that area, |lx||ly|/n + |lx||sy| + |sx||ly| + n|sx||sy|, at
                most one per texel of l and MAX_PROBES (1 for an axis-aligned rectangle)."""
                lxy = dr.abs(l_x * l_y)
                sxy = dr.abs(s_x * s_y)
                best = dr.safe_sqrt(lxy * dr.rcp(dr.maximum(sxy, 1e-12)))
                n = dr.clip(dr.round(dr.minimum(best, dr.safe_sqrt(l2))), 1.0, float(self.MAX_PROBES))
                box = (dr.abs(l_x) * dr.rcp(n) + dr.abs(s_x)) * (dr.abs(l_y) * dr.rcp(n) + dr.abs(s_y))
                return n, n * box

            # Slices along whichever edge leaves the probes less area outside the pixel.
            n_a, cover_a = slicing(ax, ay, la2, bx, by)
            n_b, cover_b = slicing(bx, by, lb2, ax, ay)
            along_a = cover_a <= cover_b
            n = dr.select(along_a, n_a, n_b)
            u_probe = dr.select(along_a, u_probe_a, u_probe_b)  # edge a: the pixel's x step
            lx, ly = dr.select(along_a, ax, bx), dr.select(along_a, ay, by)
            sx, sy = dr.select(along_a, bx, ax), dr.select(along_a, by, ay)
            # At least CELLS cells along each edge of two texels or more.
            n = dr.maximum(n, dr.select(dr.safe_sqrt(lx * lx + ly * ly) >= 2.0, float(self.CELLS), 1.0))
            v_probe = dr.select(along_a, u_probe_b, u_probe_a)
            if u_probe_a is u_probe_b:  # one number: its remainder within the slice
                v_probe = u_probe * n - dr.floor(u_probe * n)
            m = dr.select(dr.safe_sqrt(sx * sx + sy * sy) >= 2.0, float(self.CELLS), 1.0)
            offset = (dr.floor(u_probe * n) + 0.5) * dr.rcp(n) - 0.5
            offset_s = (dr.floor(v_probe * m) + 0.5) * dr.rcp(m) - 0.5
            cx = fr["x"] + dr.select(finite, offset * lx + offset_s * sx, 0.0)
            cy = fr["y"] + dr.select(finite, offset * ly + offset_s * sy, 0.0)
            sx, sy = sx * dr.rcp(m), sy * dr.rcp(m)
            # The probe: the box of the slice's own area and centre, its sides in the ratio
            # of the slice's extents (square roots of its covariance's diagonal). Where the
            # slice's ends are slanted the box cuts into it as far as it reaches beyond,
            # so the pixel's edges blur over a fraction of a slice instead of the
            # bounding box's overhang adding texels from outside the pixel: 2-10% of bias
            # at 12^2 texels sheared (bench/footprint_bias_scan.py, docs/decisions.md).
            px, py = lx * dr.rcp(n), ly * dr.rcp(n)
            var_x = px * px + sx * sx
            var_y = py * py + sy * sy
            slice_area = dr.abs(px * sy - py * sx)
            aspect = dr.sqrt(dr.sqrt(var_x * dr.rcp(dr.maximum(var_y, 1e-30))))
            area_ok = (slice_area > 1e-6) & (var_x > 0.0) & (var_y > 0.0)
            rx_fit = 0.5 * dr.sqrt(slice_area) * aspect
            ry_fit = 0.25 * slice_area * dr.rcp(dr.maximum(rx_fit, 1e-30))
            rx = dr.select(area_ok, rx_fit, 0.5 * (dr.abs(px) + dr.abs(sx)))
            ry = dr.select(area_ok, ry_fit, 0.5 * (dr.abs(py) + dr.abs(sy)))
            rx = dr.select(finite, dr.maximum(rx, 0.5), 0.5)
            ry = dr.select(finite, dr.maximum(ry, 0.5), 0.5)
            # The point branch's parallelogram (zero where not finite: the texel at si.uv).
            edges = tuple(dr.select(finite, e, 0.0) for e in (ax, ay, bx, by))
            return dict(use=use, box=(cx - rx, cy - ry, cx + rx, cy + ry), edges=edges)

        def _point_in_footprint(self, fr, fp, xi):
            """Texel coordinates of the point ``xi`` (uniform in [0,1)^2) of the footprint's
            parallelogram, where the fibre-level branch shades."""
            ax, ay, bx, by = fp["edges"]
            return (fr["x"] + (xi.x - 0.5) * ax + (xi.y - 0.5) * bx,
                    fr["y"] + (xi.x - 0.5) * ay + (xi.y - 0.5) * by)

        #: Footprint area (texels) below which shading is fibre level, above which it is the
        #: footprint's; linear blend between (docs/decisions.md).
        POINT_TEXELS = 2.0
        FOOTPRINT_TEXELS = 8.0
        #: Most probes (slices) across a footprint (more: less overhang of their boxes where
        #: the pixel is sheared, more variance between them).
        MAX_PROBES = 8
        #: Least number of cells along each edge (of 2 texels or more) of the parallelogram,
        #: probes being cells: 2 halves the bias of turned footprints (their edges blurred
        #: over smaller cells) but doubles the noise under an independent sampler (satin:
        #: bias^2 1.8e-4 -> 1.2e-4 far, noise per sample 0.047 -> 0.091; docs/decisions.md).
        CELLS = 1

        def _edges_texels(self, si):
            """The pixel footprint's edges si.duv_dx, si.duv_dy in texels of this tile."""
            su, sv = self.uv_scale * self.tile_w, self.uv_scale_v * self.tile_h
            return (si.duv_dx.x * su, si.duv_dx.y * sv), (si.duv_dy.x * su, si.duv_dy.y * sv)

        def _half_widths_texels(self, si):
            """Half-widths in texels of this tile of the footprint in si.duv_dx/dy."""
            (ax, ay), (bx, by) = self._edges_texels(si)
            return 0.5 * (dr.abs(ax) + dr.abs(bx)), 0.5 * (dr.abs(ay) + dr.abs(by))

        def _enabled(self, ctx):
            return [ctx.is_enabled(lobe_types[c], c) for c in range(6)]

        def _lobe_probabilities(self, pt, enabled):
            """Selection probabilities of the texel's lobes, proportional to each lobe's
            estimated albedo."""
            return self._lobe_weights(pt["k"], pt["wi"], pt["yarn"], pt["t_sheen_i"], self._scattered(pt), enabled,
                                      self.lobe_calibration)

        def _scattered(self, pt):
            """The share of light the texel's specular slab scatters (for its proxy)."""
            return 1.0 - spongecake.unscattered_transmittance(pt["wi"], pt["tangent"], self.roughness, self.thickness)

        def _point_proxies(self, si):
            """Unnormalised lobe proxies of the fibre-level texels of ``si`` (calibration)."""
            fr = self._frame(si, True)
            pt = self._texel(fr, fr["x"], fr["y"])
            return self._lobe_proxies(pt["k"], pt["wi"], pt["yarn"], pt["t_sheen_i"], self._scattered(pt), [True] * 6)

        def _lobe_weights(self, k, wi, yarn, ts, scattered, enabled, calibration):
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

        def _visibility_o(self, pt, wo):
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
            return v_i * self._visibility_o(pt, wo)

        def _cluster_visibilities_o(self, fr, wo):
            """Every cluster's mean V for the outgoing direction (mirrored frame)."""
            return self.footprint_data.cluster_visibilities(*self._outgoing_side(fr["flip"], wo))

        def _sheen_and_fuzz(self, fr, wo, enabled):
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
            value, fuzz = self._sheen_and_fuzz(pt, wo, enabled)
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
            pdf = dr.select(valid, self._lobes_pdf(wi, wo, probs, [t], enabled), 0.0)
            return value, pdf

        def _lobes_pdf(self, wi, wo, probs, tangents, enabled):
            """Density of picking a lobe by ``probs`` and sampling it (mirrored frame), the
            specular lobe from one of ``tangents`` chosen uniformly; validity not masked."""
            up = wo.z > 0.0
            pdf = mi.Float(0.0)
            if enabled[SHEEN]:
                pdf += probs[SHEEN] * self.sheen_sampler.pdf(wi, wo)
            if enabled[SPECULAR_REFLECTION] or enabled[SPECULAR_TRANSMISSION]:
                side_ok = (up & enabled[SPECULAR_REFLECTION]) | (_not(up) & enabled[SPECULAR_TRANSMISSION])
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

        def _footprint_state(self, si, fr, enabled, xi=None, xi_round=None, u_probe=None):
            """Everything of the footprint that does not depend on the outgoing direction,
            computed once per shading point and shared by eval, pdf and sample: the SAT
            means over the footprint, the control-variate residual texel, the viewer-side
            visibilities and the sampling mixture.

            ``xi`` (2D in [0,1)) places the residual texels, ``xi_round`` rounds the SATs'
            corners and ``u_probe`` picks the probe along the footprint (``_footprint``); by
            default all three are a hash of (si.uv, si.p), so eval is a deterministic
            function of (si, wo)."""
            fd = self.footprint_data
            sats = fd.scalar_sats
            hashed = self._hash(si)
            if xi is None:
                xi, xi_round = hashed[:2]
            xi_round = mi.Point2f(0.5, 0.5) if xi_round is None else xi_round
            fp = self._footprint(si, fr, hashed[2], u_probe)
            # The footprint shaded is its box with the corners rounded stochastically to
            # whole texels (expected extent: the footprint's), and every mean is the exact
            # mean over that rounded box: one SAT read per corner and channel instead of four
            # (these reads dominate the cost), and means that stay means. Normalised by the
            # exact area instead, the integrals were unbiased but not bounded: at 2-4 texels
            # the yarn coverage of a gap-free footprint read 0.54-1.62, so the gap lobe let
            # light through where there are no gaps (its negative values cannot be sampled)
            # and lobe probabilities reached -39 and +40 (docs/decisions.md).
            box, q = self._rounded_box(fp, xi_round)
            inv_area = dr.rcp(q.area)

            # Every channel at once (gap, moments, cluster histogram, albedo): packets of four
            # neighbouring channels per corner read. Uniformly coloured yarns stop before the
            # albedo channels (4 packets instead of 5 with 8 clusters).
            needed = sats.channels if self.uniform_yarn_albedo is None else -(-fd.ALBEDO // 4) * 4
            means = [value * inv_area for value in sats.integrals(q, 0, needed)]

            def mean(channel):
                return means[channel]

            st = dict(fp=fp, q=q, inv_area=inv_area)
            st["yarn_mean"] = yarn_mean = mean(fd.GAP)
            inv_yarn = dr.select(yarn_mean > 1e-6, dr.rcp(yarn_mean), 0.0)
            if self.uniform_yarn_albedo is not None:
                st["yarn_albedo"] = mi.Color3f(*self.uniform_yarn_albedo)
            else:
                st["yarn_albedo"] = mi.Color3f(*[mean(fd.ALBEDO + c) * inv_yarn for c in range(3)])
            if enabled[SPECULAR_REFLECTION] or enabled[SPECULAR_TRANSMISSION]:
                # The footprint's mean SGGX matrix over its yarn texels:
                # S = I - (1 - alpha^2) <t t^T>, from the mean of t t^T.
                m = [mean(fd.MOMENTS + j) * inv_yarn for j in range(6)]
                sgn = fr["sign"]
                st["moments"] = (m[0], m[1], sgn * m[2], m[3], sgn * m[4], m[5])

            # The texels of the control-variate residual, one uniform in each cell of a grid
            # over the footprint (stratified: 1/n of the variance of one texel or less).
            st["texels"] = texels = self._stratified_texels(fr, box, xi)
            if self.use_visibility:
                st["cvis_i"] = cvis_i = fd.cluster_visibilities(fr["wi"], fr["flip"])
                for t_ in texels:
                    t_["cluster"] = fd.cluster_of(t_["ix"], t_["iy"])
                    t_["vis"] = fd.texel_visibility(t_["ix"], t_["iy"])
                    t_["v_i"] = fd.visibility_of(t_["vis"], fr["wi"], fr["flip"])
                    t_["cvis_i"] = _pick(cvis_i, t_["cluster"])
                # The footprint's share of each cluster's yarn (diffuse lobes, specular base).
                st["fractions"] = [mean(fd.CLUSTERS + c) for c in range(fd.clusters)]

            # The sampling mixture: lobes chosen by the footprint's own averages (yarn
            # coverage, yarn colour, mean SGGX matrix), the specular lobe from the tangent
            # of one of the residual texels, and a defensive cosine component.
            k = _with_yarn_albedo(fr["k"], st["yarn_albedo"])
            scattered = mi.Float(0.0)
            if "moments" in st:
                sigma_i = self._mean_sigma(st, fr["wi"])
                scattered = 1.0 - spongecake.unscattered_transmittance_from(sigma_i, fr["wi"], self.thickness)
            st["fp_probs"] = self._lobe_weights(k, fr["wi"], yarn_mean, fr["t_sheen_i"], scattered, enabled,
                                                self.footprint_calibration)
            # Scaled by the square root of the yarn lobes' share: it guards them (the residual
            # texels' tangents may miss some of the footprint's), and the sheen, sampled from
            # its own table, needs no guard. A fixed share spent a tenth of the samples at
            # grazing angles, where the sheen is almost all (weight variance at 88 degrees:
            # 0.029 -> 0.001); the root keeps a little more at middle angles, where the cosine
            # still helps the transmitted flake lobe (docs/decisions.md).
            probs = st["fp_probs"]
            yarn_share = probs[SPECULAR_REFLECTION] + probs[DIFFUSE_REFLECTION] + probs[DIFFUSE_TRANSMISSION]
            st["eps_c"] = eps_c = self.DEFENSIVE_COSINE * dr.sqrt(yarn_share)
            # Its lower (transmission) share follows the diffuse lobes' split, at least a
            # tenth on either side: at grazing angles a fixed half wasted 5% of samples.
            p_dr, p_dt = probs[DIFFUSE_REFLECTION], probs[DIFFUSE_TRANSMISSION]
            diffuse = p_dr + p_dt
            lower = dr.select(diffuse > 0.0, p_dt / dr.select(diffuse > 0.0, diffuse, 1.0), 0.5)
            st["eps_lower"] = eps_c * dr.clip(lower, self.DEFENSIVE_MIN_SIDE, 1.0 - self.DEFENSIVE_MIN_SIDE)
            return st

        def _rounded_box(self, fp, xi_round):
            """The footprint's probe with its corners rounded stochastically to whole texels
            by ``xi_round`` (the box that is shaded), and its SAT query."""
            box = round_box(*fp["box"], xi_round.x, xi_round.y)
            return box, self.footprint_data.scalar_sats.query_on_grid(*box)

        @staticmethod
        def _table_tangent(fr, tangent):
            """A texel's tangent (mirrored frame) back in the maps' frame of the tables."""
            return mi.Vector3f(tangent.x, tangent.y, fr["sign"] * tangent.z)

        def _mean_sigma(self, st, w):
            """sigma(w) of the footprint's mean SGGX matrix S = I - (1 - alpha^2) <t t^T>."""
            m_xx, m_xy, m_xz, m_yy, m_yz, m_zz = st["moments"]
            alpha2 = self.roughness * self.roughness
            q = (w.x * w.x * m_xx + w.y * w.y * m_yy + w.z * w.z * m_zz
                 + 2.0 * (w.x * w.y * m_xy + w.x * w.z * m_xz + w.y * w.z * m_yz))
            return dr.safe_sqrt(dr.maximum(1.0 - (1.0 - alpha2) * q, alpha2))

        def _eval_footprint(self, fr, st, wo, enabled):
            """Footprint-averaged non-delta f*|cos o| (Eq. 9-14 with CCV), mirrored frame."""
            fd = self.footprint_data
            wi = fr["wi"]
            k = fr["k"]
            texels = st["texels"]
            cos_o = wo.z
            up = cos_o > 0.0
            valid = (wi.z > spongecake.COS_EPSILON) & (dr.abs(cos_o) > spongecake.COS_EPSILON)
            yarn_albedo = st["yarn_albedo"]

            if self.use_visibility:
                # Per residual texel: V(p, i, o) and its cluster's mean v_c(i) v_c(o).
                cvis_o = self._cluster_visibilities_o(fr, wo)
                v_p = [t_["v_i"] * self._visibility_o(t_, wo) for t_ in texels]
                vbar_p = [t_["cvis_i"] * _pick(cvis_o, t_["cluster"]) for t_ in texels]

            value, under_fuzz = self._sheen_and_fuzz(fr, wo, enabled)
            reflection = mi.Color3f(0.0)
            transmission = mi.Color3f(0.0)
            if enabled[SPECULAR_REFLECTION] or enabled[SPECULAR_TRANSMISSION]:
                h = dr.normalize(wi + wo)
                h = dr.select(h.z < 0.0, -h, h)  # D is even
                # The tables hold D of the maps' own tangents; the mirrored frame flips their
                # z, so a viewer below looks up the mirror image of h (then folded up again).
                h_table = mi.Vector3f(h.x, h.y, fr["sign"] * h.z)
                h_table = dr.select(h_table.z < 0.0, -h_table, h_table)
                # The four bins around h with their bilinear weights, deterministically: a
                # random pick of one (a quarter of the reads) was most of the estimator's own
                # noise on shiny cloth near and in the middle distance (docs/decisions.md).
                bins_h = hemisphere_bins(h_table, fd.dr)
                d_yarn = fd.d_integral(st["q"], *bins_h) * st["inv_area"]  # mean over P of D I
                # f_rs per unit D: G of the footprint's mean SGGX matrix (g_bar), and of each
                # residual texel's own tangent (g_k). The residual corrects mean(D) g_bar
                # towards mean(D g), which differ where D and the tangent correlate (grazing
                # highlights: 10-17% low without it).
                def g_of(sigma_i, sigma_o):
                    return spongecake.eval_specular_from(1.0, sigma_i, sigma_o, wi, wo, self.thickness)[0]

                g_bar = g_of(self._mean_sigma(st, wi), self._mean_sigma(st, wo))
                d_k = [sggx.ndf(h, t_["tangent"], self.roughness) * t_["yarn"] for t_ in texels]
                # The same texels' D as the tables bin it (tangents in the tables' frame): the
                # control variate that removes the bins' bias from the base.
                dbin_k = [fd.binned_ndf(*bins_h, self._table_tangent(fr, t_["tangent"]), self.roughness) * t_["yarn"]
                          for t_ in texels]
                g_k = [g_of(sggx.projected_area(wi, t_["tangent"], self.roughness),
                            sggx.projected_area(wo, t_["tangent"], self.roughness)) for t_ in texels]
                if self.use_visibility:
                    # Alg. 4's visibility: the mean v_c of the residual texels' clusters.
                    texel_mean = sum(vbar_p) * (1.0 / len(vbar_p))
                    vbar_spec = vbar_p
                    if fd.per_cluster:
                        base = mi.Float(0.0)
                        for c in range(fd.clusters):
                            base += st["cvis_i"][c] * cvis_o[c] * fd.d_integral(st["q"], *bins_h, c)
                        base *= st["inv_area"]
                    elif fd.d_cluster_tile is not None:
                        # Each cluster's visibility weighted by its share of the footprint's D:
                        # its share of the footprint times its mean D over the tile. Exact for
                        # footprints of whole tiles; Alg. 4's texel_mean (the fallback) is off
                        # by -Cov(D, v) at every size (docs/decisions.md).
                        m_c = fd.cluster_d_means(*bins_h)
                        num = mi.Float(0.0)
                        den = mi.Float(0.0)
                        for c in range(fd.clusters):
                            w_c = st["fractions"][c] * m_c[c]
                            num += w_c * st["cvis_i"][c] * cvis_o[c]
                            den += w_c
                        w_bar = dr.select(den > 0.0, num / dr.select(den > 0.0, den, 1.0), texel_mean)
                        base = d_yarn * w_bar
                        if self.CONSISTENT_VISIBILITY_CV:
                            # The residual's control variate takes the base's own visibility,
                            # so base + residual is unbiased at every footprint size; with
                            # each texel's cluster visibility instead it was 2-19% off below
                            # a tile (bench/footprint_bias_scan.py, docs/decisions.md).
                            vbar_spec = [w_bar] * len(texels)
                    else:
                        base = d_yarn * texel_mean
                    residual = mi.Float(0.0)
                    for d, db, g, v, vbar in zip(d_k, dbin_k, g_k, v_p, vbar_spec):
                        residual += d * v * g - db * vbar * g_bar
                    # An unbiased control-variate estimate: it can dip below zero for the
                    # residual texels (V(p) = 0 under a bright base); clamping it biased
                    # grazing highlights by up to +90% (docs/decisions.md), so we do not.
                    spec = base * g_bar + residual * (1.0 / len(texels))
                else:
                    residual = mi.Float(0.0)
                    for d, db, g in zip(d_k, dbin_k, g_k):
                        residual += d * g - db * g_bar
                    spec = d_yarn * g_bar + residual * (1.0 / len(texels))
                if enabled[SPECULAR_REFLECTION]:
                    reflection += k["specular_albedo"] * yarn_albedo * spec
                if enabled[SPECULAR_TRANSMISSION]:
                    transmission += k["specular_transmittance"] * yarn_albedo * spec
            if enabled[DIFFUSE_REFLECTION] or enabled[DIFFUSE_TRANSMISSION]:
                if self.use_visibility:
                    # Eq. 14 through the cluster histogram, plus the same residual texel.
                    yarn_visible = mi.Float(0.0)
                    for t_, v, vbar in zip(texels, v_p, vbar_p):
                        yarn_visible += t_["yarn"] * (v - vbar) * (1.0 / len(texels))
                    for c in range(fd.clusters):
                        yarn_visible += st["cvis_i"][c] * cvis_o[c] * st["fractions"][c]
                else:
                    yarn_visible = st["yarn_mean"]
                cosine = dr.abs(cos_o) * dr.inv_pi * yarn_visible
                if enabled[DIFFUSE_REFLECTION]:
                    reflection += k["diffuse_albedo"] * yarn_albedo * cosine
                if enabled[DIFFUSE_TRANSMISSION]:
                    transmission += k["diffuse_transmittance"] * yarn_albedo * cosine
            value += under_fuzz * dr.select(up, reflection, transmission)
            return dr.select(valid, value, 0.0)

        # The footprint BSDF is sampled as a mixture: a lobe chosen by the footprint's
        # averages (so the gap, diffuse and specular shares match the footprint form), the
        # specular lobe from one of the stratified residual texels, and a defensive cosine
        # component that keeps every direction reachable.
        DEFENSIVE_COSINE = 0.1
        #: The least share of the defensive cosine on either side of the surface.
        DEFENSIVE_MIN_SIDE = 0.1

        #: Without per-cluster tables, the specular residual's control variate takes the
        #: footprint's mean visibility (unbiased) rather than each texel's cluster's.
        CONSISTENT_VISIBILITY_CV = True

        #: The control-variate residual's texels: one in each cell of a RESIDUAL_GRID^2
        #: grid over the shaded box.
        RESIDUAL_GRID = 2

        @staticmethod
        def _strata(g):
            """(cell x, cell y, offset x, offset y) of each residual texel: the offsets of
            their shared random numbers form a rotated lattice (2x2: the quarter steps), so
            each texel stays uniform in its cell and together they spread further."""
            if g == 2:
                return ((0.0, 0.0, 0.0, 0.0), (1.0, 0.0, 0.5, 0.25), (0.0, 1.0, 0.25, 0.75), (1.0, 1.0, 0.75, 0.5))
            n = g * g
            return tuple((float(k % g), float(k // g), ((k * 7) % n) / n, ((k * 5) % n + 0.5) / n) for k in range(n))

        def _stratified_texels(self, fr, box, xi):
            """The residual texels, one uniform in each cell of the rounded box the SAT
            means cover (from ``xi``)."""
            x0, y0, x1, y1 = box
            g = self.RESIDUAL_GRID
            texels = []
            for qx, qy, cx, cy in self._strata(g):
                sx = xi.x + cx
                sy = xi.y + cy
                u = (qx + sx - dr.floor(sx)) * (1.0 / g)  # in [0, 1)
                v = (qy + sy - dr.floor(sy)) * (1.0 / g)
                texels.append(self._texel(fr, x0 + u * (x1 - x0), y0 + v * (y1 - y0)))
            return texels

        def _mixture_pdf(self, fr, st, wo, enabled):
            """Density of the footprint mixture's non-delta directions (mirrored frame)."""
            wi = fr["wi"]
            valid = (wi.z > spongecake.COS_EPSILON) & (dr.abs(wo.z) > spongecake.COS_EPSILON)
            pdf = self._lobes_pdf(wi, wo, st["fp_probs"], [t_["tangent"] for t_ in st["texels"]], enabled)
            eps_c, eps_lower = st["eps_c"], st["eps_lower"]
            eps_side = dr.select(wo.z > 0.0, eps_c - eps_lower, eps_lower)
            return dr.select(valid, (1.0 - eps_c) * pdf + eps_side * dr.abs(wo.z) * dr.inv_pi, 0.0)

        def _hash(self, si):
            """Deterministic pseudo-random numbers per shading point, from si.uv and si.p:
            (xi, xi_round, u), two 2D points and one number: the stratified texels, the
            SAT rounding, and the choice between footprint and fibre-level shading and of the
            probe (``_footprint``; xi: the point of fibre-level shading in the footprint),
            in eval(), where Mitsuba passes no random numbers. si.p
            varies between the samples of one pixel, whose footprints ``clothpath`` centres
            on the same uv. Two TEAs (~40 ops each): four words give the points their top
            24 bits each, and u the words' low bytes."""
            def bits(x):  # 24 bits of a float's fractional part
                return mi.UInt32((x - dr.floor(x)) * 16777216.0)

            a = bits(si.uv.x * 997.0 + si.uv.y * 31.0 + si.p.x * 1.618 + si.p.z * 0.577)
            b = bits(si.uv.y * 991.0 + si.uv.x * 37.0 + si.p.y * 1.414 + si.p.z * 0.318)
            v0, v1 = mi.sample_tea_32(a, b)
            v2, v3 = mi.sample_tea_32(v0, v1)

            def unit24(v):  # 24 bits -> [0, 1)
                return mi.Float(v) * (1.0 / 16777216.0)

            def unit(v):  # the top 24 bits -> [0, 1)
                return unit24(v >> 8)

            low = ((v0 & 255) << 16) | ((v1 & 255) << 8) | (v2 & 255)  # 24 bits
            return mi.Point2f(unit(v0), unit(v1)), mi.Point2f(unit(v2), unit(v3)), unit24(low)

        def _mirror(self, fr, wo):
            return mi.Vector3f(wo.x, wo.y, fr["sign"] * wo.z)

        def _sample_point(self, pt, probs, enabled, sample1, sample2, active):
            """Fibre-level sampling at one texel: (wo, ok, component, pick_gap)."""
            wi, t = pt["wi"], pt["tangent"]
            c_sheen = probs[SHEEN]
            c_spec = c_sheen + probs[SPECULAR_REFLECTION]
            c_dr = c_spec + probs[DIFFUSE_REFLECTION]
            c_dt = c_dr + probs[DIFFUSE_TRANSMISSION]
            c_all = c_dt + probs[GAP]
            pick_sheen = sample1 < c_sheen
            pick_spec = _not(pick_sheen) & (sample1 < c_spec)
            pick_dr = _not(pick_sheen) & _not(pick_spec) & (sample1 < c_dr)
            pick_dt = _not(pick_sheen) & _not(pick_spec) & _not(pick_dr) & (sample1 < c_dt)
            pick_gap = _not(pick_sheen) & _not(pick_spec) & _not(pick_dr) & _not(pick_dt) & (sample1 < c_all) & (probs[GAP] > 0.0)

            wo_spec, _ = spongecake.sample_specular(wi, t, self.roughness, sample2)
            wo_sheen = wo_spec
            if enabled[SHEEN]:
                wo_sheen, _ = self.sheen_sampler.sample(wi, sample2)
            wo_diffuse = self.diffuse_sampler.sample(sample2)
            wo_diffuse.z = dr.select(pick_dt, -wo_diffuse.z, wo_diffuse.z)
            wo = dr.select(pick_sheen, wo_sheen, dr.select(pick_spec, wo_spec, wo_diffuse))

            lands_up = wo.z > 0.0
            ok = active & (wi.z > spongecake.COS_EPSILON) & (pick_sheen | pick_spec | pick_dr | pick_dt)
            ok &= _not(pick_sheen) | lands_up
            ok &= _not(pick_spec) | dr.select(lands_up, enabled[SPECULAR_REFLECTION], enabled[SPECULAR_TRANSMISSION])
            component = dr.select(pick_sheen, SHEEN,
                        dr.select(pick_spec, dr.select(lands_up, SPECULAR_REFLECTION, SPECULAR_TRANSMISSION),
                        dr.select(pick_dr, DIFFUSE_REFLECTION, DIFFUSE_TRANSMISSION)))
            gap_ok = active & pick_gap & (wi.z > spongecake.COS_EPSILON)
            return wo, ok, mi.UInt32(component), gap_ok

        # ------------------------------------------------------------------
        # Shared by the mi.BSDF methods
        # ------------------------------------------------------------------
        def _point_branch(self, si, fr, enabled, wos, samples, active, fp=None):
            """(values, pdfs, sample record) of the fibre-level BSDF at the texel under
            si.uv (or, for a sub-texel footprint ``fp``, under a point drawn uniformly in
            it), for the mirrored directions ``wos`` and, if given, one sample."""
            x, y = fr["x"], fr["y"]
            if fp is not None:
                xi = self._hash(si)[0]
                offset = fr.get("pixel_offset")
                if offset is not None:
                    # The sample's own point of the pixel: brute force, exactly.
                    known = (offset.x >= -0.5) & (offset.y >= -0.5)
                    xi = dr.select(known, mi.Point2f(offset.x + 0.5, offset.y + 0.5), xi)
                x, y = self._point_in_footprint(fr, fp, xi)
            pt = self._texel(fr, x, y)
            if self.use_visibility and self.footprint_data is not None:
                # The texel's visibility bits, read once for every direction below.
                pt["vis"] = self.footprint_data.texel_visibility(pt["ix"], pt["iy"])
            probs = self._lobe_probabilities(pt, enabled)

            def eval_pdf(wo):
                return self._eval_pdf_point(pt, wo, enabled, probs)

            record = ()
            if samples is not None:
                wo, ok, component, gap_ok = self._sample_point(pt, probs, enabled, *samples, active)
                gap_value = fr["t_sheen_i"] * fr["t_sheen_i"] * (1.0 - pt["yarn"])
                record = self._sample_record(si, fr, eval_pdf, wo, ok, component, gap_ok, probs[GAP], gap_value)
            values, pdfs = _unzip([eval_pdf(wo) for wo in wos])
            return values, pdfs, record

        def _footprint_branch(self, si, fr, enabled, wos, samples, active):
            """The same for the footprint BSDF (multi-scale shading)."""
            st = self._footprint_state(si, fr, enabled)

            def eval_pdf(wo):
                return self._eval_footprint(fr, st, wo, enabled), self._mixture_pdf(fr, st, wo, enabled)

            record = ()
            if samples is not None:
                record = self._sample_record(si, fr, eval_pdf, *self._sample_footprint(fr, st, enabled, *samples, active))
            values, pdfs = _unzip([eval_pdf(wo) for wo in wos])
            return values, pdfs, record

        def _sample_footprint(self, fr, st, enabled, sample1, sample2, active):
            """A direction from the footprint mixture:
            (wo mirrored, ok, component, gap_ok, gap_pdf, gap_value)."""
            texels, fp_probs, eps_c = st["texels"], st["fp_probs"], st["eps_c"]
            # Split sample1: defensive cosine | the footprint's lobes; within the specular
            # share, which of the residual texels lends its tangent.
            pick_def_cos = sample1 < eps_c
            u = (sample1 - eps_c) / (1.0 - eps_c)
            u_spec = (u - fp_probs[SHEEN]) / dr.select(fp_probs[SPECULAR_REFLECTION] > 0.0,
                                                       fp_probs[SPECULAR_REFLECTION], 1.0)
            quad = mi.UInt32(dr.clip(dr.floor(u_spec * len(texels)), 0, len(texels) - 1))
            chosen = dict(texels[0])
            for q in range(1, len(texels)):
                chosen["tangent"] = dr.select(quad == q, texels[q]["tangent"], chosen["tangent"])

            wo, ok, component, gap_ok = self._sample_point(chosen, fp_probs, enabled, u, sample2, active)
            wo_cos = mi.warp.square_to_cosine_hemisphere(sample2)
            # The defensive cosine side: the lower or upper part of its sample1 slice.
            lower = sample1 < st["eps_lower"]
            wo_cos.z = dr.select(lower, -wo_cos.z, wo_cos.z)
            wo = dr.select(pick_def_cos, wo_cos, wo)
            viewer_ok = active & (fr["wi"].z > spongecake.COS_EPSILON)
            ok = dr.select(pick_def_cos, viewer_ok, ok)
            component = dr.select(pick_def_cos, dr.select(lower, DIFFUSE_TRANSMISSION, DIFFUSE_REFLECTION),
                                  component)
            gap_ok &= _not(pick_def_cos)
            gap_pdf = (1.0 - eps_c) * fp_probs[GAP]
            gap_value = fr["t_sheen_i"] * fr["t_sheen_i"] * (1.0 - st["yarn_mean"])
            return wo, ok, component, gap_ok, gap_pdf, gap_value

        def _sample_record(self, si, fr, eval_pdf, wo, ok, component, gap_ok, gap_pdf, gap_value):
            """(wo in the world's local frame, pdf, component, weight) of a sampled
            mirrored direction, or of the gap."""
            value, pdf = eval_pdf(wo)
            ok &= pdf > 0.0
            weight = dr.select(ok, value / dr.select(ok, pdf, 1.0), 0.0)
            gap_ok &= gap_pdf > 0.0
            gap_weight = gap_value / dr.select(gap_ok, gap_pdf, 1.0)
            return (dr.select(gap_ok, -si.wi, self._mirror(fr, wo)),
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
            known), which picks its probe (``_footprint``) and fibre-level point.

            Footprints of a texel or more take the multi-scale branch, smaller ones the
            fibre-level one; a symbolic if, so a packet of lanes that all take one branch
            skips the other's work."""
            enabled = self._enabled(ctx)
            fr = self._frame(si, active)
            fr["pixel_offset"] = pixel_offset
            wos = [self._mirror(fr, wo) for wo in wos]
            if not self.multiscale:
                values, pdfs, record = self._point_branch(si, fr, enabled, wos, samples, active)
            else:
                fp = self._footprint(si, fr, self._hash(si)[2])
                values, pdfs, record = _branch(
                    fp["use"], (si, wos, samples),
                    true_fn=lambda: self._footprint_branch(si, fr, enabled, wos, samples, active),
                    false_fn=lambda: self._point_branch(si, fr, enabled, wos, samples, active, fp),
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
            fr = self._frame(si, active)
            xi, xi_round, u = self._hash(si)

            if not self.multiscale:
                yarn = self._texel(fr, fr["x"], fr["y"])["yarn"]
            else:
                fp = self._footprint(si, fr, u)
                sats = self.footprint_data.scalar_sats

                def texel_yarn():  # at the point the fibre-level branch shades
                    return self._texel(fr, *self._point_in_footprint(fr, fp, xi))["yarn"]

                def footprint_yarn():
                    # One read per corner of the rounded box (exact corners took four, and
                    # were most of what a shadow ray crossing cloth cost). Its mean stays in
                    # [0, 1]: over the exact area it did not, and the clip below then let
                    # light through gap-free footprints (docs/decisions.md).
                    _, q = self._rounded_box(fp, xi_round)
                    return sats.integral(q, self.footprint_data.GAP) / q.area

                # Packets whose lanes all have a footprint skip the texel read; packets
                # without one (shadow rays from vertices shaded at a point) the table reads.
                yarn = _branch(fp["use"] & active, (si, active), true_fn=footprint_yarn,
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
