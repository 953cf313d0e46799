"""The ``cloth`` plugin's documentation: one table of its parameters, from which both the
plugin docstring's list-table (:data:`DOCSTRING`) and README.md's table
(``scripts/gen_docs.py``) are generated.

The flags of each parameter (exposed, differentiable) are not repeated here: they come from
:data:`.parameters.EXPOSED`, which ``traverse`` follows. Cells are written in Markdown
(```code```); the docstring gets them in reStructuredText (````code````).
tests/test_parameter_docs.py checks that every parameter :func:`.parameters.read_parameters`
accepts has exactly one row, that the defaults are the code's, and that README.md holds
what the script generates.
"""
from __future__ import annotations

import re
import textwrap
from dataclasses import dataclass

from .parameters import exposure_text


@dataclass(frozen=True)
class ParameterDoc:
    """One row of the ``cloth`` parameter table."""

    name: str
    #: "string", "integer", "float", "boolean" or "spectrum or texture".
    type: str
    #: The default as the docs show it (checked against the code's by the tests).
    default: str
    #: What it does, its range, and what it costs; Markdown, one paragraph.
    meaning: str


#: The parameters of ``cloth``, in the order the docs list them.
PARAMETER_DOCS: tuple[ParameterDoc, ...] = (
    ParameterDoc(
        "fabric", "string", "none",
        "A fabric preset (`mscloth fabrics`; README.md's Fabrics) or a `.json` preset file "
        "(relative to the scene file): its maps at the true thread count and defaults for every "
        "parameter below, which still override it; UVs are then read in metres (`uv_unit` 1)."),
    ParameterDoc(
        "pattern", "string", "`plain`",
        "Cloth maps: a pattern name (`plain`, `twill-2-1`, `satin-8-3`, `basket-2`, `jersey`, "
        "`rib-2-2`...), a `.wif` draft file, or a directory written by `mscloth maps` / "
        "`ClothMaps.save`. Relative paths are found as Mitsuba finds a mesh's `filename`: first "
        "in the scene file's directory. With `fabric` and no `pattern`: the fabric's own maps."),
    ParameterDoc(
        "resolution", "integer", "0",
        "Texels along u when generating a pattern, in [8, 8192]. 0: 32 per thread within [128, "
        "320] texels (knits 64 per wale within [64, 320]; at least 8 per thread or wale, up to "
        "1024; moved into the widths a tall or wide tile takes); with `fabric`, the fabric's own (16 per end, 8 for linen and 4 for silk "
        "shantung, whose slubby tiles are long, twice that per wale, within [32, 512])."),
    ParameterDoc(
        "uv_scale", "float", "1.0",
        "Pattern tiles per UV unit, > 0 (along u, and along v unless `uv_scale_v` is given)."),
    ParameterDoc(
        "uv_unit", "float", "0 (1 with `fabric`)",
        "Length of one UV unit in metres, for meshes with physical UVs: sets `uv_scale` and "
        "`uv_scale_v` from the tile's size in mm, so a fabric shows the same yarn size on any "
        "mesh. Not with `uv_scale` or `uv_scale_v`."),
    ParameterDoc(
        "uv_scale_v", "float", "0",
        "Pattern tiles per UV unit along v (0: `uv_scale` × the tile's width / height, so a "
        "square UV unit shows the weave at its true aspect); a Mitsuba `sphere` (u spans twice "
        "the length of v) wants half of that."),
    ParameterDoc(
        "roughness", "float", "0.3",
        "Fibre roughness α ∈ (0, 1]: the SGGX matrix is S = α² t tᵀ + (I − t tᵀ) for fibre "
        "tangent t (docs/design.md §3). With `multiscale` it is also baked into the "
        "directional SAT: changing it rebuilds those tables (cached) and the lobe calibration."),
    ParameterDoc(
        "thickness", "float", "2.0",
        "Optical thickness T > 0 of the yarn layer (SpongeCake)."),
    ParameterDoc(
        "specular_albedo", "spectrum or texture", "0.4",
        "k_rs ∈ [0, 1] of specular fibre reflection, times the maps' yarn albedo."),
    ParameterDoc(
        "specular_transmittance", "spectrum or texture", "0.2",
        "k_ts ∈ [0, 1] of specular fibre transmission, times the maps' yarn albedo."),
    ParameterDoc(
        "diffuse_albedo", "spectrum or texture", "0.4",
        "k_rd ∈ [0, 1] of diffuse (multiply scattered) reflection, times the maps' yarn albedo."),
    ParameterDoc(
        "diffuse_transmittance", "spectrum or texture", "0.1",
        "k_td ∈ [0, 1] of diffuse transmission, times the maps' yarn albedo."),
    ParameterDoc(
        "sheen_color", "spectrum or texture", "0.5",
        "Albedo of the fuzz fibres, ∈ [0, 1]."),
    ParameterDoc(
        "sheen_roughness", "float", "0.5",
        "Roughness of the fuzz fibres (standing along the normal), ∈ (0, 1]."),
    ParameterDoc(
        "sheen_thickness", "float", "0.2",
        "Optical thickness of the fuzz layer, ≥ 0 (0: no sheen)."),
    ParameterDoc(
        "multiscale", "boolean", "true",
        "Shade whole pixel footprints (summed-area tables + CCV); needs `clothpath`, or any "
        "integrator that sets `si.duv_dx/dy`. false: fibre level, one texel."),
    ParameterDoc(
        "visibility", "boolean", "true",
        "Shadowing × masking by the cloth's height field, V(p, i, o), at fibre level and in "
        "the footprint (via CCV)."),
    ParameterDoc(
        "unbiased_ccv", "boolean", "false",
        "Per-cluster control-variate base Σ_c v̄_c ∫_{P∩c} D: each residual texel's control "
        "variate takes its own cluster's visibility (less noise below a tile), for 8× the "
        "directional SAT memory and about twice the shading time. Both bases are unbiased: "
        "the default one weighs each cluster's visibility by its share of the footprint's D "
        "(the cluster histogram and each cluster's mean D over the tile), and below a tile "
        "the residual's control variate takes that same mean visibility "
        "(docs/architecture.md)."),
    ParameterDoc(
        "parallax", "boolean", "false",
        "Shift lookups (and the footprint) to where the view ray meets the height field "
        "(supplement Alg. 3); non-reciprocal, hence off by default. Its table is built only "
        "when on."),
    ParameterDoc(
        "direction_bins", "integer", "0",
        "Half-vector bins per side of the directional SAT (dr), 0 or in [4, 64]; 0: from the "
        "roughness (16 at 0.2 and above, 32 down to 0.08, 48 below), fine enough for the "
        "fibres' lobe."),
    ParameterDoc(
        "visibility_bins", "integer", "8",
        "Direction bins per side of the visibility (and parallax) tables, in [2, 32]."),
    ParameterDoc(
        "clusters", "integer", "8",
        "Visibility clusters (k-means) of the control variates, in [1, 32]."),
    ParameterDoc(
        "direction_rank", "integer", "0",
        "Rank K of the compressed directional SAT (0: full, `direction_bins`² channels, unless "
        "that exceeds `max_table_mib`; at most `direction_bins`²): K channels and a basis over "
        "the bins (PCA of the tile's D). 64 keeps footprint means within ~0.5% at roughness "
        "0.3 (64-texel footprints) and brings a 512², dr = 32 table from 1 GiB to 64 MiB, for "
        "about twice the shading time."),
    ParameterDoc(
        "max_table_mib", "integer", "256",
        "Memory budget (MiB) of the full directional SAT, in [16, 2^20]. A tile whose full "
        "table is larger (512² texels at 32² bins: 1 GiB) gets rank 64 instead, or the largest "
        "rank that fits, with a warning; raise it to keep the faster full table."),
    ParameterDoc(
        "footprint_slices", "integer", "1",
        "No longer used (accepted for older scenes, with a warning unless 1): a footprint is "
        "the pixel's parallelogram, shaded one probe per sample (see the footprint convention "
        "under `clothpath`)."),
)

#: What the Flags column means (README.md and the plugin docstring).
FLAGS_NOTE = (
    "Flags, as in Mitsuba's plugin docs: **P** exposed by `mi.traverse` (set it, then "
    "`params.update()`), **∂** differentiable, **D** discontinuous (none here). A parameter is "
    "differentiable where evaluating the BSDF reads it live; `roughness` is also baked into the "
    "footprint's directional tables, so with `multiscale` it carries no gradient, and changing it "
    "rebuilds those tables (cached) and the lobe calibration. A render differentiates through "
    "Mitsuba's `prb` or `direct` (which shade cloth at points); `clothpath` refuses gradients with "
    "one line, since its samples follow lobe and texel choices a gradient cannot see. Parameters "
    "marked — are read once: "
    "reload the scene to change them. A texture given for a spectrum is a `bitmap` or a "
    "`checkerboard` (of constants, bitmaps or checkerboards): textures whose values can be bounded, "
    "since the albedos are checked, when loaded and after `params.update()`, to lie in [0, 1] and "
    "to create no light.")


def to_rst(text: str) -> str:
    """Markdown cell text in reStructuredText: ``code`` spans doubled, **bold** kept."""
    return re.sub(r"(?<!`)`([^`]+)`(?!`)", r"``\1``", text)


def markdown_table() -> str:
    """The README's parameter table, with the Flags column of :data:`.parameters.EXPOSED`."""
    lines = ["| Parameter | Type | Default | Meaning | Flags |", "|---|---|---|---|---|"]
    for p in PARAMETER_DOCS:
        lines.append(f"| `{p.name}` | {p.type} | {p.default} | {p.meaning} | {exposure_text(p.name)} |")
    return "\n".join(lines)


def markdown_section() -> str:
    """What README.md holds between its ``parameters`` markers."""
    return "\n".join(textwrap.wrap(FLAGS_NOTE, 92)) + "\n\n" + markdown_table()


def rst_list_table() -> str:
    """The docstring's list-table, without the Flags column, which the plugin class adds
    (:func:`.parameters.with_flags_column`, from the same :data:`.parameters.EXPOSED`)."""
    lines = [".. list-table::", "   :header-rows: 1", "",
             "   * - Parameter", "     - Type", "     - Default", "     - Meaning"]
    for p in PARAMETER_DOCS:
        meaning = textwrap.wrap(to_rst(p.meaning), 80)
        lines += [f"   * - {p.name}", f"     - {p.type}", f"     - {to_rst(p.default)}",
                  f"     - {meaning[0]}", *(f"       {line}" for line in meaning[1:])]
    return "\n".join(lines)


_INTRO = r"""
Multi-scale surface-based cloth (``cloth``)
-------------------------------------------

Fibre-level cloth BSDF of Zhu et al. 2024 (supplement Eq. 1-8; docs/design.md §3): a sheen
layer of fuzz over a SpongeCake layer of fibre-like SGGX flakes whose tangents come from
cloth maps, with diffuse lobes for light scattered many times inside the yarns and delta
transmission through the gaps between yarns::

    f = f_sheen + T_sheen I (f_rs + f_rd) + T_sheen I (f_ts + f_td) + T_sheen (1 - I) f_delta

The cloth is thin and two-sided: viewer and light may be on either side; the back side
sees the same maps mirrored through the surface.

"""

_OUTRO = r"""

Multi-scale shading takes the pixel footprint as the parallelogram spanned by
``si.duv_dx`` and ``si.duv_dy`` around ``si.uv``: cut along one edge into at most 16 slices
(those whose bounding boxes cover least area; one for an axis-aligned rectangle), one slice
per sample shaded whole as the box of its own area and centre. Footprints under 16 texels
are shaded fibre level at a point drawn in the parallelogram, those over 32 texels whole,
and those between by one or the other, with a weight linear in the area. The directional
tables are read over the three half-vector bins around h (barycentric weights), visibility
over four (bilinear) (docs/architecture.md).

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

#: The plugin's docstring, its list-table generated from :data:`PARAMETER_DOCS`; the plugin
#: class adds the Flags column (``with_flags_column``).
DOCSTRING = (_INTRO + "\n".join(textwrap.wrap(to_rst(FLAGS_NOTE), 88)) + "\n\n" + rst_list_table()
             + _OUTRO)
