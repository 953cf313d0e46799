"""Fabric presets: complete parameter sets, true thread counts, physical UV scale, the
swatch scene."""
import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import mscloth
from cloth_fixtures import non_delta_context
from mscloth.errors import ParameterError
from mscloth.fabrics import FABRICS, fabric
from mscloth.maps.woven import float_heights

mscloth.register()

REQUIRED = {"silk-charmeuse", "polyester-satin", "cotton-poplin", "denim", "wool-gabardine",
            "linen", "silk-shantung", "silk-organza", "cotton-jersey", "wool-rib"}


def test_the_issue_s_fabrics_are_all_there_and_documented():
    assert REQUIRED <= set(FABRICS)
    for f in FABRICS.values():
        assert f.source and f.look, f.name
        assert f.structure in ("woven", "knit")


@pytest.mark.parametrize("name", sorted(REQUIRED))
def test_maps_have_the_stated_thread_count_and_gap_fraction(name):
    f = fabric(name)
    maps = f.maps()
    width_mm, height_mm = maps.meta["tile_size_mm"]
    if f.structure == "woven":
        n_weft, n_warp = np.asarray(maps.meta["drawdown"]).shape
        assert width_mm == pytest.approx(n_warp * 10.0 / f.ends_per_cm)
        assert height_mm == pytest.approx(n_weft * 10.0 / f.picks_per_cm)
        warp_ids = np.unique(maps.yarn_id[(maps.yarn_id >= 0) & (maps.yarn_id < n_warp)])
        assert len(warp_ids) == n_warp  # every warp end of the repeat shows
        # Texel-centre sampling moves a yarn's edge by up to half a texel on each side.
        texels_per_thread = maps.resolution[1] / n_warp
        tolerance = 2.0 / texels_per_thread
        assert abs((1.0 - maps.gap.mean()) - f.gap_fraction) <= tolerance, name
    else:
        stitches = np.asarray(maps.meta["stitches"])
        n_courses, n_wales = stitches.shape
        assert width_mm == pytest.approx(n_wales * 10.0 / f.ends_per_cm)
        assert height_mm == pytest.approx(n_courses * 10.0 / f.picks_per_cm)
    dense = {"silk-charmeuse", "polyester-satin", "cotton-poplin", "denim", "wool-gabardine"}
    if name in dense:
        assert maps.gap.mean() == 1.0, f"{name} is dense: no gaps"
    if name == "silk-organza":
        assert 1.0 - maps.gap.mean() > 0.25, "organza is sheer: open gaps"


def test_fabric_sets_defaults_that_parameters_override():
    b = mi.load_dict({"type": "cloth", "fabric": "denim", "roughness": 0.2, "multiscale": False,
                      "visibility": False})
    assert dr.allclose(b.params.roughness, 0.2)
    assert dr.allclose(b.params.thickness, fabric("denim").thickness)
    assert dr.allclose(b.params.sheen_thickness, fabric("denim").sheen_thickness)
    assert b.maps.meta["fabric"] == "denim"


def test_cloth_constructor_loads_no_scene_of_its_own(monkeypatch):
    """A ``cloth`` is built on one of the parallel loader's threads; a nested
    ``mi.load_dict`` there corrupts the file resolver that ``sunsky`` or a mesh reads at
    the same moment (Mitsuba 3.9.1: 1 scene load in 10-20 failed with std::bad_alloc). A
    preset's colours are made through the plugin manager instead."""
    real, depth, nested = mi.load_dict, [0], []

    def counting(scene, *args, **kwargs):
        if depth[0]:
            nested.append(scene)
        depth[0] += 1
        try:
            return real(scene, *args, **kwargs)
        finally:
            depth[0] -= 1

    monkeypatch.setattr(mi, "load_dict", counting)
    b = mi.load_dict({"type": "cloth", "fabric": "wool-gabardine", "multiscale": False, "visibility": False})
    assert nested == []
    # and the preset's sheen colour still arrives as the scene parser would make it
    expected = real(fabric("wool-gabardine").bsdf_parameters()["sheen_color"])
    si = dr.zeros(mi.SurfaceInteraction3f)
    assert dr.allclose(b.params.textures["sheen_color"].eval(si), expected.eval(si))


def test_unknown_fabric_names_the_closest():
    from mscloth.loading import load_dict
    with pytest.raises(ParameterError, match="did you mean 'silk-charmeuse'"):
        load_dict({"type": "cloth", "fabric": "silk-charmeus"})


def test_unknown_fabric_suggests_the_presets_that_hold_the_word():
    """`--fabric silk` named none: its three presets are too far by spelling alone."""
    from mscloth.fabrics import fabric

    with pytest.raises(ParameterError, match=r"unknown fabric 'silk' \(did you mean 'silk-charmeuse', "
                                             r"'silk-shantung' or 'silk-organza'\?\)"):
        fabric("silk")
    with pytest.raises(ParameterError, match=r"\(did you mean 'wool-gabardine' or 'wool-rib'\?\)"):
        fabric("wool")


def test_uv_unit_and_uv_scale_are_exclusive():
    from mscloth.loading import load_dict

    with pytest.raises(ParameterError, match="not both"):
        load_dict({"type": "cloth", "fabric": "denim", "uv_unit": 1.0, "uv_scale": 3.0,
                      "multiscale": False, "visibility": False})


def _eval_along(bsdf, uv_per_mm: float, x_mm: np.ndarray):
    """Fibre-level BSDF at points x_mm along u of a mesh with ``uv_per_mm`` UV units per mm."""
    n = len(x_mm)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.uv = mi.Point2f(mi.Float(x_mm * uv_per_mm), mi.Float(np.full(n, 0.37 * uv_per_mm)))
    si.wi = mi.Vector3f(0.3, 0.2, 0.93)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    return np.array(bsdf.eval(non_delta_context(), si, mi.Vector3f(-0.2, 0.1, 0.97)))


def test_same_fabric_same_yarn_size_whatever_the_uv_unit():
    """A mesh in metres and one in decimetres (UV units 10x apart) show the same yarns at
    the same physical positions."""
    x_mm = np.linspace(0.0, 3.0, 997)
    common = {"type": "cloth", "fabric": "denim", "multiscale": False, "visibility": False}
    metres = mi.load_dict(dict(common, uv_unit=1.0))
    decimetres = mi.load_dict(dict(common, uv_unit=0.1))
    assert dr.allclose(metres.params.uv_scale, 10.0 * decimetres.params.uv_scale)
    a = _eval_along(metres, 1e-3, x_mm)
    b = _eval_along(decimetres, 1e-2, x_mm)
    assert np.std(a) > 0.05 * np.mean(a)  # the weave varies along the line
    assert np.allclose(a, b, rtol=1e-3, atol=1e-5)
    # One tile per tile_size_mm: a fabric's default reads UVs in metres.
    default = mi.load_dict(common)
    width_mm = default.maps.meta["tile_size_mm"][0]
    assert dr.allclose(default.params.uv_scale, 1000.0 / width_mm)


def test_float_heights_arch_long_floats_and_keep_plain_weave():
    plain = np.array([[1.0, -1.0], [-1.0, 1.0]])
    assert np.array_equal(float_heights(plain, 1.0), plain)
    satin_column = np.array([[-1.0], [1.0], [1.0], [1.0], [1.0]])
    arched = float_heights(satin_column, 1.0)[:, 0]
    s1, s2 = math.sin(math.pi / 5), math.sin(2 * math.pi / 5)
    assert np.allclose(arched, [-1.0, 2 * s1 - 1, 2 * s2 - 1, 2 * s2 - 1, 2 * s1 - 1])
    assert np.array_equal(float_heights(satin_column, 0.0), satin_column)
    # A run that wraps around the repeat arches as one float.
    wrapped = np.roll(satin_column, 2, axis=0)
    assert np.allclose(float_heights(wrapped, 1.0), np.roll(float_heights(satin_column, 1.0), 2, axis=0))


def test_every_preset_renders_without_nan():
    """Every preset's parameters through the multi-scale BSDF and clothpath, all in one
    scene (one kernel for all): a row of squares under a sky and a low sun, each a finite,
    lit patch of the image (tiles of 64 texels, or 2 per warp end where a preset has more
    ends, so the tables build in a second; the presets' own maps are checked above)."""
    from mscloth.loading import load_dict

    names = sorted(REQUIRED)
    n = len(names)
    T = mi.ScalarTransform4f
    scene = {"type": "scene", "integrator": {"type": "clothpath", "max_depth": 3},
             "sensor": {"type": "orthographic",
                        "to_world": T().look_at(origin=[0, -1, 3], target=[0, 0, 0], up=[0, 1, 0])
                        @ T().scale([n * 0.5, 0.5, 1.0]),
                        "film": {"type": "hdrfilm", "width": 8 * n, "height": 8, "rfilter": {"type": "box"}}},
             "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [0.4, 0.45, 0.5]}},
             "sun": {"type": "directional", "direction": [0.4, 0.5, -0.6],
                     "irradiance": {"type": "rgb", "value": [3.0, 3.0, 3.0]}}}

    def texels(name):
        meta = fabric(name).maps().meta
        return max(64, 2 * len(meta["drawdown"][0])) if "drawdown" in meta else 64

    for i, name in enumerate(names):
        # Squares of 0.9 x 0.9 units side by side, each filling its 8 x 8 pixels.
        scene[f"swatch-{i}"] = {"type": "rectangle",
                                "to_world": T().translate([(i - (n - 1) / 2) * 1.0, 0.0, 0.0]) @ T().scale(0.49),
                                "bsdf": {"type": "cloth", "fabric": name, "resolution": texels(name),
                                         "uv_scale": 8.0}}
    image = np.array(mi.render(load_dict(scene), spp=2, seed=1))
    assert np.all(np.isfinite(image))
    for i, name in enumerate(names):
        patch = image[2:6, 8 * i + 2:8 * i + 6]
        assert patch.mean() > 0.01, name


@pytest.mark.parametrize("view,light", [("close", "studio"), ("room", "sunsky")])
def test_swatch_views_and_lights(view, light, tmp_path):
    from mscloth.loading import load_dict
    from mscloth.scenes.swatch import swatch_scene

    scene = load_dict(swatch_scene(24, 18, "silk-charmeuse", view, light, mesh_dir=tmp_path))
    image = np.array(mi.render(scene, spp=2, seed=1))
    assert np.all(np.isfinite(image)) and image.mean() > 0.0


def test_swatch_sunsky_is_exposed_as_the_studio_rig(tmp_path):
    """The two rigs light the arm's-length view alike (means within a factor 1.5): the
    sunsky's scale was once ~30x too dark for Mitsuba's sunsky, an almost black picture."""
    from mscloth.loading import load_dict
    from mscloth.scenes.swatch import swatch_scene

    means = [np.array(mi.render(load_dict(swatch_scene(32, 24, "denim", "arm", light, mesh_dir=tmp_path)),
                                spp=4, seed=1))[..., :3].mean() for light in ("studio", "sunsky")]
    assert 1 / 1.5 < means[1] / means[0] < 1.5, means


def test_fabric_file_starts_from_a_base_and_resolves_beside_the_scene(tmp_path, monkeypatch):
    import json

    from mscloth.loading import load_file

    sub = tmp_path / "scene"
    sub.mkdir()
    (sub / "black-denim.json").write_text(json.dumps(
        {"base": "denim", "warp_color": [0.05, 0.05, 0.05], "roughness": 0.45}))
    (sub / "scene.xml").write_text(
        '<scene version="3.0.0"><shape type="rectangle"><bsdf type="cloth" id="c">'
        '<string name="fabric" value="black-denim.json"/><boolean name="multiscale" value="false"/>'
        '<boolean name="visibility" value="false"/></bsdf></shape></scene>')
    monkeypatch.chdir(tmp_path)  # not the scene's directory
    scene = load_file(str(sub / "scene.xml"))
    bsdf = scene.shapes()[0].bsdf()
    assert bsdf.maps.meta["fabric"] == "black-denim"
    assert dr.allclose(bsdf.params.roughness, 0.45)
    assert dr.allclose(bsdf.params.thickness, fabric("denim").thickness)  # from the base
    warp = bsdf.maps.albedo[bsdf.maps.yarn_id == 0]
    assert np.allclose(warp, (0.05 / 12.92), atol=1e-4)  # sRGB 0.05 -> linear


def test_fabric_file_errors_name_the_file_and_field(tmp_path):
    import json

    from mscloth.fabrics import load_fabric_file

    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"base": "denim", "rouhgness": 0.3}))
    with pytest.raises(ParameterError, match=r"bad.json: unknown field 'rouhgness' \(did you mean 'roughness'\?\)"):
        load_fabric_file(bad)
    bad.write_text(json.dumps({"base": "denim", "roughness": "shiny"}))
    with pytest.raises(ParameterError, match="bad.json: field 'roughness' must be a number"):
        load_fabric_file(bad)
    bad.write_text("{")
    with pytest.raises(ParameterError, match="bad.json: not valid JSON"):
        load_fabric_file(bad)
    with pytest.raises(ParameterError, match="does not exist"):
        fabric(str(tmp_path / "missing.json"))


# ---------------------------------------------------------------- slubs, rib relief, seams
SLUBBY = ("linen", "silk-shantung")


@pytest.mark.parametrize("name", SLUBBY)
def test_slubs_vary_the_diameter_along_each_yarn(name):
    """A slubby preset's yarns thicken along their length (not from thread to thread):
    at each crossing where a yarn is over, its surface stands A (1 + f) above the cloth's
    mid-plane, f its diameter factor there (slub_factors with the maps' own seed), so
    along a yarn its crossings' heights range over the preset's slub amplitude."""
    from mscloth.maps.woven import slub_factors

    f = fabric(name)
    maps = f.maps()
    meta = maps.meta
    dd = np.asarray(meta["drawdown"], dtype=bool)
    n_weft, n_warp = dd.shape
    width_mm, height_mm = meta["tile_size_mm"]
    H, W = maps.resolution
    amplitudes = meta["slub"]
    # Tiles hold at least one slub spacing along each slubby yarn: slubs fall irregularly,
    # not once per thread per tile.
    for length, amp in zip((height_mm, width_mm), amplitudes):
        assert amp == 0.0 or length >= f.slub_spacing_mm - 1e-9
    yh = meta["yarn_height"]
    kw = {"length_mm": tuple(meta["slub_length_mm"]), "spacing_mm": meta["slub_spacing_mm"]}
    rows = ((np.arange(n_weft) + 0.5) * H / n_weft).astype(int)   # texel at each pick's centre
    cols = ((np.arange(n_warp) + 0.5) * W / n_warp).astype(int)
    h_mm = maps.height * width_mm
    for family, amp in zip(("warp", "weft"), amplitudes):
        if family == "warp":
            spacing, diam, over = 10.0 / f.ends_per_cm, f.yarn_diameter_mm[0], dd
            pos = (rows + 0.5) * height_mm / H
            fac = slub_factors(n_warp, height_mm, amp, pos, seed=[meta["slub_seed"], 0], **kw).T
            heights = h_mm[np.ix_(rows, cols)]                               # (picks, ends)
        else:
            spacing, diam, over = 10.0 / f.picks_per_cm, f.yarn_diameter_mm[-1], ~dd.T
            pos = (cols + 0.5) * width_mm / W
            fac = slub_factors(n_weft, width_mm, amp, pos, seed=[meta["slub_seed"], 1], **kw).T
            heights = h_mm[np.ix_(rows, cols)].T                             # (ends, picks)
        A = 0.5 * yh * min(diam, spacing)
        # (Texel centres lie up to half a texel off the crossing: a few % lower at 4 per end.)
        assert np.allclose(heights[over], A * (1.0 + fac[over]), rtol=0.06), family
        if amp > 0.0:
            assert np.corrcoef(heights[over], fac[over])[0, 1] > 0.98, family
        ratio = np.array([fac[over[:, k], k].max() / fac[over[:, k], k].min() for k in range(over.shape[1])])
        if amp == 0.0:
            assert np.allclose(ratio, 1.0)
        else:
            # Crossings sample a slub within a quarter spacing of its peak (slubs >= 2 mm).
            assert 1.0 + 0.75 * amp <= ratio.max() <= 1.0 + amp + 1e-9, (family, ratio)
            assert np.mean(ratio > 1.0 + 0.25 * amp) > 0.4   # most yarns carry slubs
    assert np.any(np.asarray(amplitudes) > 0)


def test_wool_rib_knit_wales_stand_proud_of_its_purl_wales():
    """Close up the rib must read as ribs: the knit wales' tops stand at least 0.8 yarn
    diameters above the purl wales' (they lay level before rib_depth)."""
    f = fabric("wool-rib")
    maps = f.maps()
    stitches = np.asarray(maps.meta["stitches"])
    nw = stitches.shape[1]
    h_mm = maps.height * maps.meta["tile_size_mm"][0]
    per = maps.resolution[1] // nw
    tops = np.array([np.percentile(h_mm[:, j * per + per // 4:(j + 1) * per - per // 4], 90)
                     for j in range(nw)])
    knit = stitches.mean(axis=0) == 1
    assert tops[knit].min() - tops[~knit].max() >= 0.8 * f.yarn_diameter_mm[0], tops


@pytest.mark.parametrize("name", ["cotton-jersey", "wool-rib"])
def test_knit_preset_tile_edges_are_like_any_wale_or_course_boundary(name):
    """No seam at the tile's edges: the maps of the preset's stitches rolled by one wale
    (one course) are its maps rolled by one wale's (course's) texels."""
    from mscloth.maps.knit import knit_maps

    maps = fabric(name).maps()
    m = maps.meta
    stitches = np.asarray(m["stitches"])
    nc, nw = stitches.shape
    H, W = maps.resolution
    kw = dict(yarn_width=m["yarn_width"], loop_aspect=m["loop_aspect"], loop_height=m["loop_height"],
              leg_tilt_deg=m["leg_tilt_deg"], yarn_height=m["yarn_height"],
              fibre_twist_deg=m["fibre_twist_deg"], rib_depth=m["rib_depth"])
    assert W % nw == 0
    for axis, count, size in ((1, nw, W), (0, nc, H)):
        if size % count:
            continue  # (wool-rib: 137 texels for 5 courses; its wales are checked)
        texels = size // count
        rolled = knit_maps(np.roll(stitches, 1, axis=axis), (H, W), **kw)
        for field in ("height", "normal", "tangent", "gap"):
            a = np.roll(np.asarray(getattr(maps, field)), texels, axis=axis)
            assert np.allclose(getattr(rolled, field), a, atol=1e-5), (field, axis)


@pytest.mark.parametrize("fabric,view", [("cotton-jersey", "close"), ("silk-charmeuse", "arm")])
def test_swatch_under_area_lights_matches_fibre_level_shading(fabric, view):
    """The gallery's views (studio rig of area lights, clothpath's tent uv_filter): multi-scale
    shading and fibre-level shading render the same mean brightness. In the jersey's close
    view, footprints of a few texels inside the knit's gaps once had a NaN density, which
    clothpath's MIS turned into emitter weights of their squared density: +11% overall,
    +125% under the rim light."""
    from mscloth.loading import load_dict
    from mscloth.scenes.swatch import swatch_scene

    means = []
    for multiscale in (True, False):
        scene = swatch_scene(240, 180, fabric, view)
        assert scene["integrator"]["uv_filter"] == "tent"
        scene["cloth"]["bsdf"]["multiscale"] = multiscale
        image = np.array(mi.render(load_dict(scene), spp=4, seed=3))[..., :3]
        assert np.all(np.isfinite(image))
        means.append(image.mean())
    # The image means' own noise at 4 spp over 43,200 pixels is ~0.3%.
    assert means[0] == pytest.approx(means[1], rel=0.03), means


# ---------------------------------------------------------------- fabric values are checked
def _fabric_file(tmp_path, data, name="f.json"):
    import json

    path = tmp_path / name
    path.write_text(json.dumps(data))
    return path


def _load_error(path) -> str:
    """The one-line ParameterError that loading the fabric file ``path`` raises."""
    from mscloth.fabrics import load_fabric_file

    with pytest.raises(ParameterError) as error:
        load_fabric_file(path)
    message = str(error.value)
    assert "\n" not in message, message
    return message


def test_every_preset_passes_the_checks_unchanged_and_without_warnings(tmp_path):
    """Presets are checked as they are built; building each again (and from a file with it
    as base) gives the same fabric, with no warning."""
    import dataclasses
    import warnings

    from mscloth.fabrics import load_fabric_file

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for name, preset in FABRICS.items():
            assert dataclasses.replace(preset) == preset, name
            loaded = load_fabric_file(_fabric_file(tmp_path, {"base": name}, f"{name}.json"))
            assert loaded == dataclasses.replace(preset, name=name), name


def test_fabric_file_zero_thread_count_names_the_field(tmp_path):
    message = _load_error(_fabric_file(tmp_path, {"base": "denim", "ends_per_cm": 0}))
    assert message.endswith("f.json: field 'ends_per_cm' must be > 0, got 0"), message


def test_fabric_file_negative_thread_count_names_the_field(tmp_path):
    message = _load_error(_fabric_file(tmp_path, {"base": "denim", "ends_per_cm": -5}))
    assert message.endswith("f.json: field 'ends_per_cm' must be > 0, got -5"), message


def test_fabric_file_colour_must_be_an_srgb_triple(tmp_path):
    message = _load_error(_fabric_file(tmp_path, {"base": "denim", "warp_color": "black"}))
    assert "f.json: field 'warp_color' must be an sRGB triple [r, g, b] of numbers in [0, 1]" in message
    assert message.endswith("got 'black'"), message
    message = _load_error(_fabric_file(tmp_path, {"base": "denim", "sheen_color": [0, 128, 255]}))
    assert "field 'sheen_color' must be an sRGB triple" in message


def test_fabric_file_naming_itself_as_base_is_a_cycle(tmp_path):
    path = _fabric_file(tmp_path, {"base": "f.json"})
    message = _load_error(path)
    assert message == f"fabric file {path}: field 'base' makes a cycle: {path} -> f.json", message


def test_fabric_file_base_chain_through_other_files_is_a_cycle(tmp_path, monkeypatch):
    """Bases are found beside the file that names them, wherever the working directory is."""
    _fabric_file(tmp_path, {"base": "b.json"}, "a.json")
    _fabric_file(tmp_path, {"base": "a.json", "roughness": 0.2}, "b.json")
    monkeypatch.chdir(tmp_path.parent)
    message = _load_error(tmp_path / "a.json")
    assert message.endswith("a.json: field 'base' makes a cycle: "
                            f"{tmp_path / 'a.json'} -> b.json -> a.json"), message
    # A chain without a cycle still loads.
    _fabric_file(tmp_path, {"base": "denim", "roughness": 0.2}, "b.json")
    from mscloth.fabrics import load_fabric_file
    assert load_fabric_file(tmp_path / "a.json").roughness == 0.2


def test_fabric_file_pattern_must_fit_the_base_structure(tmp_path):
    message = _load_error(_fabric_file(tmp_path, {"base": "cotton-jersey", "pattern": "twill-2-1"}))
    assert ("f.json: field 'pattern' 'twill-2-1' is a weave, but field 'structure' is 'knit' "
            "(from base 'cotton-jersey'): give a knit pattern (jersey, rib-K-P") in message, message
    message = _load_error(_fabric_file(tmp_path, {"base": "denim", "pattern": "rib-2-2"}))
    assert "field 'pattern' 'rib-2-2' is a knit, but field 'structure' is 'woven'" in message


def test_fabric_file_inclination_out_of_range_names_the_field(tmp_path):
    message = _load_error(_fabric_file(tmp_path, {"base": "denim", "inclination_deg": 500}))
    assert message.endswith("f.json: field 'inclination_deg' must be in (0, 90) degrees, got 500"), message
    message = _load_error(_fabric_file(tmp_path, {"base": "denim", "inclination_deg": 0}))
    assert "field 'inclination_deg' must be in (0, 90)" in message  # a flat weave has no yarn_height


def test_fabric_file_yarn_far_wider_than_its_spacing_warns(tmp_path):
    from mscloth.fabrics import load_fabric_file

    path = _fabric_file(tmp_path, {"base": "denim", "yarn_diameter_mm": [100, 100]})
    with pytest.warns(UserWarning, match=r"f.json: field 'yarn_diameter_mm': the warp yarn \(100 mm\) "
                                         r"is 280x its spacing \(0.357 mm\)") as record:
        load_fabric_file(path)
    assert len(record) == 1 and "\n" not in str(record[0].message)


@pytest.mark.parametrize("change,expected", [
    ({"picks_per_cm": "many"}, "field 'picks_per_cm' must be a number"),
    ({"fibre_twist_deg": 120}, "field 'fibre_twist_deg' must be in [-90, 90], got 120"),
    ({"roughness": 0}, "field 'roughness' must be in (0, 1], got 0"),
    ({"specular_albedo": 1.5}, "field 'specular_albedo' must be in [0, 1], got 1.5"),
    ({"diffuse_albedo": 0.9}, "fields 'diffuse_albedo' + 'diffuse_transmittance' + max("),
    ({"yarn_diameter_mm": [0.4, 0]}, "field 'yarn_diameter_mm' must be > 0 mm, got 0"),
    ({"yarn_diameter_mm": [0.4, 0.4, 0.4]}, "field 'yarn_diameter_mm' must be one diameter in mm"),
    ({"ply": 2.5}, "field 'ply' must be a whole number in [1, 8], got 2.5"),
    ({"repeat": 0}, "field 'repeat' must be a whole number >= 1, got 0"),
    ({"repeat": 400}, "fields 'repeat', 'texels_per_thread', 'ends_per_cm' and 'picks_per_cm' give a tile"),
    ({"slub": [0.2, 9]}, "field 'slub' must be in [0, 4], got 9"),
    ({"slub_length_mm": [8, 2]}, "field 'slub_length_mm' must be (shortest, longest) in mm"),
    ({"slub_tone": 3}, "field 'slub_tone' must be in [0.5, 2], got 3"),
    ({"structure": "felt"}, "field 'structure' must be 'woven' or 'knit', got 'felt'"),
    ({"pattern": "twirl"}, "field 'pattern': unknown pattern 'twirl'"),
    ({"base": "denimm"}, "field 'base': unknown fabric 'denimm' (did you mean 'denim'?)"),
])
def test_fabric_file_other_bad_values_name_their_field(tmp_path, change, expected):
    message = _load_error(_fabric_file(tmp_path, {"base": "denim", **change}))
    assert f"f.json: {expected}" in message, message


def test_fabric_file_knit_loops_bound_the_thread_counts(tmp_path):
    message = _load_error(_fabric_file(tmp_path, {"base": "cotton-jersey", "picks_per_cm": 100}))
    assert "f.json: fields 'ends_per_cm' / 'picks_per_cm' (wales / courses per cm) of a knit must be in " \
           "[0.3, 3]" in message, message
    message = _load_error(_fabric_file(tmp_path, {"base": "cotton-jersey", "yarn_diameter_mm": [0.3, 0.3]}))
    assert "field 'yarn_diameter_mm' must be one diameter in mm (a knit has one yarn)" in message


def test_fabric_built_in_python_is_checked_as_a_file_is():
    import dataclasses

    from mscloth.fabrics import Fabric

    with pytest.raises(ParameterError, match=r"^fabric 'mine': field 'ends_per_cm' must be > 0, got 0$"):
        dataclasses.replace(fabric("denim"), name="mine", ends_per_cm=0)
    with pytest.raises(ParameterError, match=r"^fabric 'mine': field 'warp_color' must be an sRGB triple"):
        dataclasses.replace(fabric("denim"), name="mine", warp_color="black")
    with pytest.raises(ParameterError, match=r"^fabric 'mine': field 'pattern' 'jersey' is a knit, but "
                                             r"field 'structure' is 'woven': give a weave pattern"):
        dataclasses.replace(fabric("denim"), name="mine", pattern="jersey")
    with pytest.warns(UserWarning, match="^fabric 'mine': field 'yarn_diameter_mm'"):
        dataclasses.replace(fabric("denim"), name="mine", yarn_diameter_mm=(100.0, 100.0))
    # Lists become tuples: a Fabric is hashed (its maps are cached).
    mine = dataclasses.replace(fabric("denim"), name="mine", warp_color=[0.1, 0.2, 0.3], repeat=[2, 1])
    assert mine.warp_color == (0.1, 0.2, 0.3) and mine.repeat == (2, 1) and hash(mine)
    assert isinstance(mine, Fabric)


def test_the_bsdf_ranges_a_fabric_is_checked_by_are_the_plugins():
    # fabrics.py keeps a copy (importing the plugin's table would pull in Mitsuba).
    from mscloth.bsdf.parameters import FLOAT_PARAMETERS
    from mscloth.fabrics import FIELD_RANGES

    shared = set(FIELD_RANGES) & set(FLOAT_PARAMETERS)
    assert {"roughness", "thickness", "sheen_roughness", "sheen_thickness"} <= shared
    for name in shared:
        _, low, high, low_inclusive, _ = FLOAT_PARAMETERS[name]
        assert FIELD_RANGES[name] == (low, high, not low_inclusive, False), name
