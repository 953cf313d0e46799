"""The ``cloth`` BSDF plugin: wires cloth maps and parameters into the lobes of
supplement Eq. 1, and Mitsuba's BSDF interface into the variant-agnostic units that shade:

* :mod:`.parameters`: what the plugin reads, what the tables are built from;
* :mod:`.fibre_bsdf`: the fibre-level BSDF at a texel (:class:`.FibreBSDF`), over the
  named state of :mod:`.shading_state` and the lobe mixture of :mod:`.lobe_mixture`;
* :mod:`.footprint_estimator`: the footprint (multi-scale) BSDF over it;
* :mod:`.cloth_shading`: one shading call, footprint or fibre level;
* :mod:`.lobe_calibration`: the lobe choice matched to the lobes' albedos.

The maths lives in :mod:`mscloth.scattering`. Plugin classes bind to the Mitsuba variant
active when they are defined, so :func:`make_cloth_class` builds one class per variant
(see :mod:`.registry`); the class holds only what binds to Mitsuba.
"""
from __future__ import annotations

import itertools

import drjit as dr
import mitsuba as mi
import numpy as np

from ..errors import ParameterError
from .cloth_shading import ClothShading
from .fibre_bsdf import FibreBSDF, ShadingParameters, TileTables
from .footprint_data import FootprintData
from .footprint_estimator import FootprintEstimator
from .lobe_calibration import calibrate
from .lobe_mixture import LobeSamplers
from .lobes import component_flags, enabled_lobes
from .parameters import (EXPOSED, FLOAT_PARAMETERS, _check_float, cloth_maps, exposure_flags, read_parameters,
                         uv_scales, with_flags_column)


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

Flags (as in Mitsuba's plugin docs): P exposed by ``mi.traverse`` (set it, then
``params.update()``), ∂ differentiable, D discontinuous. A parameter is differentiable where
evaluation reads it live; roughness is baked into the footprint's directional tables, so it
is not differentiable with ``multiscale``, and changing it rebuilds them (cached). Parameters
marked "—" are read once: reload the scene to change them.

.. list-table::
   :header-rows: 1

   * - Parameter
     - Type
     - Default
     - Meaning
   * - fabric
     - string
     - none
     - A fabric preset (:mod:`mscloth.fabrics`, ``mscloth fabrics``) or a ``.json``
       preset file (relative to the scene file): its maps at the
       true thread count and defaults for every parameter below, which still override
       it; UVs are then read in metres (``uv_unit`` 1).
   * - pattern
     - string
     - ``plain``
     - Cloth maps: a pattern name (``plain``, ``twill-2-1``, ``satin-8-3``,
       ``basket-2``, ``jersey``, ``rib-2-2``...), a ``.wif`` draft file, or a
       directory written by ``ClothMaps.save`` / ``mscloth maps``. Relative paths are
       found as Mitsuba finds a mesh's ``filename``: first in the scene file's directory.
   * - resolution
     - integer
     - 0
     - Texels along u when generating a pattern (0: 32 per thread, in [128, 320]; knits
       64 per wale, in [64, 320]; at least 8 per thread or wale up to 1024).
   * - uv_scale
     - float
     - 1.0
     - Pattern tiles per UV unit, > 0 (along u, and along v unless
       ``uv_scale_v`` is given).
   * - uv_unit
     - float
     - 0 (1 with ``fabric``)
     - Length of one UV unit in metres, for meshes with physical UVs: sets ``uv_scale``
       and ``uv_scale_v`` from the tile's size in mm. Not with ``uv_scale``.
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
``si.duv_dx`` and ``si.duv_dy`` around ``si.uv``: cut along one edge into at most 16 slices
(those whose bounding boxes cover least area; one for an axis-aligned rectangle), one slice
per sample shaded whole as the box of its own area and centre. Footprints under 2 texels are shaded fibre level at a point drawn in the
parallelogram, those over 8 texels whole, and those between by one or the other, with a
weight linear in the area. Direction bins of the tables are read with their bilinear
weights.

Sampling picks one lobe by an estimate of its albedo, calibrated when the BSDF is built
(and when its roughness changes) against measured lobe albedos
(``bsdf/lobe_calibration.py``; JIT variants), and samples it exactly (visible normals,
cosine); the weight is the whole mixture's eval over its pdf. Other changed parameters keep
the calibration: it steers the choice of lobe only, never the estimate's expectation.

Per channel, diffuse_albedo + diffuse_transmittance + max(specular_albedo,
specular_transmittance) must not exceed 1, so that no configuration creates
energy. Components (for ``BSDFContext.component``): 0 sheen, 1 specular
reflection, 2 diffuse reflection, 3 specular transmission, 4 diffuse
transmission, 5 gap (delta transmission).
"""


def make_cloth_class():
    """Define the ``cloth`` BSDF class for the active Mitsuba variant."""

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
            self.params = ShadingParameters(
                **{name: self._parameter(name, value) for name, value in (
                    ("uv_scale", uv_scale), ("uv_scale_v", uv_scale_v), ("roughness", p.roughness),
                    ("thickness", p.thickness), ("sheen_roughness", p.sheen_roughness),
                    ("sheen_thickness", p.sheen_thickness))},
                textures=p.textures)
            self.fibre = FibreBSDF(self.params, TileTables.from_maps(maps), p.build.visibility, p.build.parallax)
            self.multiscale = p.build.multiscale
            # Read by clothpath: footprints are shaded whole, so centre them on the pixel.
            self.footprint_shading = p.build.multiscale
            if p.footprint_slices != 1:
                mi.Log(mi.LogLevel.Warn, f"cloth [{self.label}]: footprint_slices is no longer used: footprints are "
                                         "shaded as the pixel's parallelogram (one probe per sample)")
            self.m_components = component_flags()
            flags = 0
            for f in self.m_components:
                flags |= f
            self.m_flags = flags
            self._build_tables()
            self.fibre.samplers = LobeSamplers.for_fuzz(self.params.sheen_roughness, p.sheen_roughness,
                                                        p.sheen_thickness)
            self._calibrate(uv_scale, uv_scale_v)

        # ------------------------------------------------------------------
        # What is built from parameters: tables, calibration
        # ------------------------------------------------------------------
        @property
        def estimator(self) -> FootprintEstimator | None:
            """The footprint (multi-scale) estimator, None at fibre level."""
            return self.shading.estimator

        @property
        def footprint_data(self) -> FootprintData | None:
            """The precomputed tables in Dr.Jit memory (None when none are needed)."""
            return self.fibre.footprint_data

        def _build_tables(self):
            """The multi-scale tables of ``self.build`` (cached: :func:`load_or_build`) in
            Dr.Jit memory, and the footprint estimator that reads them."""
            b = self.build
            self.fibre.footprint_data = None
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
                self.fibre.footprint_data = FootprintData(tables, with_sats=b.multiscale, with_parallax=b.parallax)
            # The footprint BSDF; before calibration, which samples it.
            self.shading = ClothShading(self.fibre, FootprintEstimator(self.fibre) if b.multiscale else None)

        def _calibrate(self, uv_scale, uv_scale_v):
            """Lobe selection matched to the lobes' albedos, and for footprints to the
            footprint mixture's weights, measured on the BSDF as it is now, at the uv scales
            given (JIT variants; scalar variants, for unit tests, keep the uncalibrated
            proxies)."""
            self.fibre.calibration = None
            if self.estimator is not None:
                self.estimator.calibration = None
            if dr.is_jit_v(mi.Float):
                texel_uv = None
                if self.multiscale:
                    tile = self.fibre.tile
                    texel_uv = (1.0 / (uv_scale * tile.tile_w), 1.0 / (uv_scale_v * tile.tile_h))
                with dr.suspend_grad():
                    self.fibre.calibration, footprint_calibration = calibrate(
                        self, self.fibre.point_proxies, self.estimator, texel_uv)
                if self.estimator is not None:
                    self.estimator.calibration = footprint_calibration

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
            value = getattr(self.params, name)
            if not dr.is_jit_v(mi.Float):
                return float(value)
            return float(str(np.float32(dr.detach(value)[0])))

        # ------------------------------------------------------------------
        # mi.BSDF interface
        # ------------------------------------------------------------------
        def sample(self, ctx, si, sample1, sample2, active=True):
            return self.shading.shade(enabled_lobes(ctx), si, [], (sample1, sample2), active)[2]

        def eval_pdf(self, ctx, si, wo, active=True):
            values, pdfs, _ = self.shading.shade(enabled_lobes(ctx), si, [wo], None, active)
            return values[0], pdfs[0]

        def eval(self, ctx, si, wo, active=True):
            return self.eval_pdf(ctx, si, wo, active)[0]

        def pdf(self, ctx, si, wo, active=True):
            return self.eval_pdf(ctx, si, wo, active)[1]

        def eval_pdf_sample_n(self, ctx, si, wos, sample1, sample2, active=True, pixel_offset=None):
            """eval_pdf at every direction of ``wos`` and one sample, sharing one footprint
            state (SAT means, visibilities, the sampling mixture: all independent of the
            outgoing direction). Called by ``clothpath`` through ``dr.dispatch``, which
            passes the camera sample's ``pixel_offset`` at first hits
            (:meth:`.ClothShading.shade`)."""
            values, pdfs, (bs, weight) = self.shading.shade(enabled_lobes(ctx), si, wos, (sample1, sample2),
                                                            active, pixel_offset)
            return values, pdfs, bs, weight

        def eval_pdf_sample(self, ctx, si, wo, sample1, sample2, active=True):
            values, pdfs, bs, weight = self.eval_pdf_sample_n(ctx, si, [wo], sample1, sample2, active)
            return values[0], pdfs[0], bs, weight

        def footprint_texels(self, si, active=True):
            """Full widths (u, v) in texels of this tile of the footprint in si.duv_dx/dy
            (the ``footprint_texels_*`` AOVs of clothpath)."""
            return self.shading.footprint_texels(si, active)

        def gap_transmission(self, si, active=True):
            """Fraction of light crossing the cloth straight along -si.wi through its gaps
            (clothpath's shadow rays; :meth:`.ClothShading.gap_transmission`)."""
            return self.shading.gap_transmission(si, active)

        # ------------------------------------------------------------------
        # Parameters: traverse, parameters_changed
        # ------------------------------------------------------------------
        def traverse(self, callback):
            # Flags from parameters.EXPOSED: differentiable where eval reads the value live.
            for name in EXPOSED:
                value = self.params.textures[name] if name in self.params.textures else getattr(self.params, name)
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
                    self._pin(name, getattr(self.params, name))
            if "uv_scale_v" in changed and keys:
                self._uv_aspect = None  # given now
            elif "uv_scale" in changed and self._uv_aspect is not None:
                # A v scale derived from uv_scale (and the tile's aspect) stays so, as when loaded.
                v = self._value("uv_scale") * self._uv_aspect
                if dr.is_jit_v(mi.Float):
                    mi.set_property(self.params.uv_scale_v, mi.Float(v))  # in place: params holds it
                else:
                    self.params.uv_scale_v = v
                self._pin("uv_scale_v", self.params.uv_scale_v)
            if changed & {"sheen_roughness", "sheen_thickness"}:
                self.fibre.samplers = LobeSamplers.for_fuzz(self.params.sheen_roughness, self._value("sheen_roughness"),
                                                            self._value("sheen_thickness"))
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
            p = self.params
            return (f"ClothBSDF[pattern={self.pattern!r} ({w}x{h} texels), uv_scale={p.uv_scale}, "
                    f"roughness={p.roughness}, thickness={p.thickness}, "
                    f"sheen_roughness={p.sheen_roughness}, sheen_thickness={p.sheen_thickness}]")

    ClothBSDF.__name__ = "ClothBSDF"
    return ClothBSDF
