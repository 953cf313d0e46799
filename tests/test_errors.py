"""Bad input raises a clear error naming the parameter and what was expected."""
import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import mscloth
from mscloth.errors import MapsError, ParameterError, PatternError
from mscloth.loading import load_dict

mscloth.register()


@pytest.mark.parametrize("params,needle", [
    ({"roughness": -0.1}, "'roughness'"),
    ({"roughness": 0.0}, "'roughness'"),
    ({"roughness": 1.5}, "(0, 1]"),
    ({"thickness": 0.0}, "'thickness'"),
    ({"thickness": float("nan")}, "'thickness'"),
    ({"uv_scale": -2.0}, "'uv_scale'"),
    ({"sheen_thickness": -1.0}, "'sheen_thickness'"),
    ({"sheen_roughness": 2.0}, "'sheen_roughness'"),
    ({"diffuse_albedo": 1.2}, "'diffuse_albedo'"),
    ({"specular_albedo": -0.2}, "'specular_albedo'"),
    ({"sheen_color": {"type": "rgb", "value": [0.2, 1.4, 0.2]}}, "'sheen_color'"),
    ({"diffuse_albedo": 0.6, "diffuse_transmittance": 0.3, "specular_albedo": 0.5}, "must be <= 1"),
    ({"resolution": 3}, "'resolution'"),
    ({"multiscale": 1.0}, "'multiscale'"),
    ({"direction_bins": 2}, "'direction_bins'"),
    ({"clusters": 0}, "'clusters'"),
    ({"visibility_bins": 100}, "[2, 32]"),
])
def test_out_of_range_parameters(params, needle):
    with pytest.raises(ParameterError, match=None) as info:
        load_dict(dict({"type": "cloth"}, **params))
    assert needle in str(info.value)


def test_plain_mitsuba_loading_still_shows_our_message():
    with pytest.raises(RuntimeError, match="'roughness' .* must be in"):
        mi.load_dict({"type": "cloth", "roughness": -1.0})


def test_unknown_pattern_names_the_choices():
    with pytest.raises(PatternError, match="unknown pattern 'houndstooth-xyz'.*plain"):
        load_dict({"type": "cloth", "pattern": "houndstooth-xyz"})


def test_missing_maps_directory(tmp_path):
    # A path (it has a separator) names a directory that is missing, not an unknown name.
    missing = str(tmp_path / "nowhere")
    with pytest.raises(PatternError, match=f"maps directory '{missing}' does not exist"):
        load_dict({"type": "cloth", "pattern": missing})
    with pytest.raises(PatternError, match="maps directory 'maps/nowhere' does not exist.*working directory"):
        load_dict({"type": "cloth", "pattern": "maps/nowhere"})


def test_corrupt_maps_directory(tmp_path):
    from mscloth.maps.builtin import resolve_pattern

    directory = tmp_path / "maps"
    resolve_pattern("plain", 16).save(directory)
    npz = directory / "maps.npz"
    npz.write_bytes(npz.read_bytes()[:200])  # truncated
    with pytest.raises(MapsError, match="maps.npz"):
        load_dict({"type": "cloth", "pattern": str(directory)})


def test_maps_directory_is_used(tmp_path):
    from mscloth.maps.builtin import resolve_pattern

    directory = tmp_path / "mine"
    resolve_pattern("plain", 32).save(directory)
    bsdf = load_dict({"type": "cloth", "pattern": str(directory)})
    assert "32x32" in str(bsdf)


def test_wrong_type():
    with pytest.raises(ParameterError, match="'roughness'.*number"):
        load_dict({"type": "cloth", "roughness": "rough"})


def test_misspelled_parameter_is_named_with_the_closest_one():
    with pytest.raises(ParameterError, match=r"unknown parameter 'sheen_thicknes': did you mean 'sheen_thickness'\?"):
        load_dict({"type": "cloth", "sheen_thicknes": 0.3})
    with pytest.raises(ParameterError, match=r"unknown parameter 'Roughness': did you mean 'roughness'\?"):
        load_dict({"type": "cloth", "Roughness": 0.3})
    # Nothing close: the names it takes instead.
    with pytest.raises(ParameterError, match=r"unknown parameter 'glitter': expected one of fabric, pattern, resolution, "):
        load_dict({"type": "cloth", "glitter": 1.0})


def test_suggestions_come_from_the_documented_parameters():
    import re

    from mscloth.bsdf.cloth import DOCSTRING
    from mscloth.bsdf.parameters import PARAMETER_NAMES

    documented = set()
    for row in re.findall(r"^   \* - (.+)$", DOCSTRING, re.MULTILINE):
        documented.update(name.strip() for name in row.split(","))
    documented.discard("Parameter")
    assert documented == set(PARAMETER_NAMES)
    # Every documented parameter is taken as it is spelled.
    load_dict({"type": "cloth", "pattern": "plain", "resolution": 16, "multiscale": False, "visibility": False})


def _cloth_scene_file(path, *bsdf_lines: str):
    """A scene file of one rectangle whose cloth ``<bsdf>`` (line 3) holds ``bsdf_lines``."""
    body = "".join(f"            {line}\n" for line in bsdf_lines)
    path.write_text('<scene version="3.0.0">\n    <shape type="rectangle">\n        <bsdf type="cloth">\n'
                    f'{body}        </bsdf>\n    </shape>\n</scene>\n')
    return path


def _cli_render_error_lines(scene, tmp_path, capsys) -> list[str]:
    """The non-blank lines ``mscloth render SCENE`` prints on stderr, where it fails (exit 2)."""
    from mscloth.cli import main

    assert main(["render", str(scene), "--out", str(tmp_path / "x.exr")]) == 2
    return [line for line in capsys.readouterr().err.splitlines() if line.strip()]


def test_cli_names_a_misspelled_parameter_in_a_scene_file(tmp_path, capsys):
    scene = _cloth_scene_file(tmp_path / "typo.xml", '<float name="sheen_thicknes" value="0.3"/>')
    lines = _cli_render_error_lines(scene, tmp_path, capsys)
    assert len(lines) == 1, lines
    assert f"{scene} line 3: " in lines[0] and "'sheen_thicknes'" in lines[0] and "'sheen_thickness'" in lines[0]
    # Another plugin's misspelling: Mitsuba's message, with the name it lists on its next line.
    scene.write_text(scene.read_text().replace('type="cloth"', 'type="diffuse"').replace(
        'float name="sheen_thicknes" value="0.3"', 'rgb name="reflectanc" value="0.3"'))
    lines = _cli_render_error_lines(scene, tmp_path, capsys)
    assert len(lines) == 1 and lines[0].endswith('of type "diffuse": reflectanc'), lines
    assert not (tmp_path / "x.exr").exists()


# ----------------------------------------------------------------------------------------
# Albedos changed through mi.traverse are checked as the constructor checks them
# ----------------------------------------------------------------------------------------
from mscloth.bsdf.parameters import ENERGY_PARAMETERS, SPECTRUM_PARAMETERS, constant_channels  # noqa: E402

LIGHT_CLOTH = {"type": "cloth", "pattern": "plain", "resolution": 16, "multiscale": False, "visibility": False}


@pytest.mark.parametrize("value", [5.0, -1.0, float("nan"), float("inf")])
@pytest.mark.parametrize("name", list(SPECTRUM_PARAMETERS))
def test_an_albedo_out_of_range_through_traverse_is_an_error(name, value):
    """Before the fix only the float parameters were checked on update: an albedo of 5
    made the cloth create light, one of -1 black, with no error."""
    bsdf = mi.load_dict(LIGHT_CLOTH)
    params = mi.traverse(bsdf)
    params[f"{name}.value"] = mi.Float(value)
    with pytest.raises(ParameterError) as info:
        params.update()
    message = str(info.value)
    assert f"parameter '{name}'" in message and "must lie in [0, 1] in every channel" in message, message
    assert message.startswith("cloth [") and "\n" not in message


@pytest.mark.parametrize("name,value", [("diffuse_albedo", 0.55), ("diffuse_transmittance", 0.25),
                                        ("specular_albedo", 0.55), ("specular_transmittance", 0.55)])
def test_an_albedo_that_creates_light_through_traverse_is_an_error(name, value):
    """Each value is in [0, 1], but with the defaults of the others the sum is 1.05."""
    assert set(ENERGY_PARAMETERS) == {"diffuse_albedo", "diffuse_transmittance", "specular_albedo",
                                      "specular_transmittance"}
    bsdf = mi.load_dict(LIGHT_CLOTH)
    params = mi.traverse(bsdf)
    params[f"{name}.value"] = mi.Float(value)
    with pytest.raises(ParameterError, match=r"cloth \[.*\]: diffuse_albedo \+ diffuse_transmittance \+ "
                                             r"max\(specular_albedo, specular_transmittance\) must be <= 1.*got 1.05"):
        params.update()


def test_an_rgb_albedo_through_traverse_is_checked_per_channel():
    bsdf = mi.load_dict(dict(LIGHT_CLOTH, diffuse_albedo={"type": "rgb", "value": [0.1, 0.2, 0.45]}))
    params = mi.traverse(bsdf)
    params["diffuse_albedo.value"] = mi.Color3f(0.1, 1.5, 0.2)
    with pytest.raises(ParameterError, match=r"parameter 'diffuse_albedo' .* must lie in \[0, 1\]"):
        params.update()
    params["diffuse_albedo.value"] = mi.Color3f(0.1, 0.2, 0.6)  # in range, but 0.6 + 0.1 + 0.4 > 1 in B
    with pytest.raises(ParameterError, match="got 1.1 in channel B"):
        params.update()


def test_a_valid_albedo_through_traverse_is_taken_also_after_a_refused_one():
    bsdf = mi.load_dict(LIGHT_CLOTH)
    params = mi.traverse(bsdf)
    params["diffuse_albedo.value"] = mi.Float(5.0)
    with pytest.raises(ParameterError, match="'diffuse_albedo'"):
        params.update()
    # Exactly at the bound: 0.5 + 0.1 + max(0.4, 0.2) = 1.
    params["diffuse_albedo.value"] = mi.Float(0.5)
    params["specular_albedo.value"] = mi.Float(0.35)
    params.update()
    textures = bsdf.params.textures
    np.testing.assert_allclose(constant_channels(textures["diffuse_albedo"]), 0.5)
    np.testing.assert_allclose(constant_channels(textures["specular_albedo"]), 0.35)
    si = dr.zeros(mi.SurfaceInteraction3f, 1)
    si.wi = mi.Vector3f(0.0, 0.0, 1.0)
    si.uv = mi.Point2f(0.3, 0.3)
    value = np.array(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(0.0, 0.6, 0.8)))
    assert np.all(np.isfinite(value)) and np.all(value > 0.0)


def test_texture_albedos_through_traverse_are_checked():
    """A bitmap's data and a checkerboard's colours, changed through traverse, are bounded
    as the constructor bounds them."""
    def data(value):
        return mi.TensorXf(np.full((2, 2, 3), value, dtype=np.float32))

    bsdf = mi.load_dict(dict(LIGHT_CLOTH, diffuse_albedo={"type": "bitmap", "data": data(0.2), "raw": True},
                             specular_transmittance={"type": "checkerboard", "color0": 0.1, "color1": 0.2}))
    params = mi.traverse(bsdf)
    params["diffuse_albedo.data"] = data(1.5)
    with pytest.raises(ParameterError, match=r"parameter 'diffuse_albedo' .* got values in \[1.5, 1.5\]"):
        params.update()
    params["diffuse_albedo.data"] = data(0.3)
    params.update()
    params["specular_transmittance.color1.value"] = mi.Float(0.7)  # 0.2 + 0.1 + 0.7 > 1
    with pytest.raises(ParameterError, match="must be <= 1 .*got 1"):
        params.update()
    params["specular_transmittance.color1.value"] = mi.Float(float("nan"))
    with pytest.raises(ParameterError, match="parameter 'specular_transmittance'"):
        params.update()


def _small_cloth_scene(bsdf: dict):
    return mi.load_dict({
        "type": "scene", "integrator": {"type": "clothpath", "max_depth": 4},
        "sensor": {"type": "perspective", "fov": 35,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 3], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 8, "height": 8}},
        "sky": {"type": "constant", "radiance": 0.8},
        "cloth": {"type": "rectangle", "bsdf": bsdf}})


@pytest.mark.parametrize("updates", [
    {"thickness": -3.0}, {"sheen_thickness": -1.0}, {"roughness": -1.0}, {"diffuse_albedo.value": 5.0},
    {"diffuse_transmittance.value": 0.9},
    {"thickness": 0.5, "specular_albedo.value": 1.5, "sheen_color.value": 0.4},  # all or nothing
], ids=lambda updates: ",".join(updates))
def test_a_refused_update_keeps_the_previous_values(updates):
    """Mitsuba writes the new values before the BSDF checks them: before the fix a refused
    update left them in place, and the next render shaded with a thickness of -3 (values
    down to -4e11). Now every parameter of the update is back at its last accepted value,
    and the cloth renders as before."""
    scene = _small_cloth_scene(dict(LIGHT_CLOTH, uv_scale=12.0))
    params = mi.traverse(scene)
    keys = {name: f"cloth.bsdf.{name}" for name in updates}
    before = {key: np.array(params[key]) for key in keys.values()}
    image = np.array(mi.render(scene, spp=4, seed=1))
    for name, value in updates.items():
        params[keys[name]] = mi.Float(value)
    with pytest.raises(ParameterError) as info:
        params.update()
    names = ", ".join(name.removesuffix(".value") for name in updates)
    assert str(info.value).endswith(f"; kept the previous value{'s' if len(updates) > 1 else ''} of {names}")
    for key, value in before.items():
        np.testing.assert_array_equal(np.array(mi.traverse(scene)[key]), value, err_msg=key)
    np.testing.assert_allclose(np.array(mi.render(scene, spp=4, seed=1)), image, rtol=1e-6, atol=1e-7)


def test_a_refused_texture_update_keeps_the_previous_texture():
    """A bitmap's data and a checkerboard's colour, refused, are put back: the textures
    evaluate as before (the bitmap's lookup data rebuilt from them too)."""
    data = mi.TensorXf(np.full((2, 2, 3), 0.2, dtype=np.float32))
    bsdf = mi.load_dict(dict(LIGHT_CLOTH, diffuse_albedo={"type": "bitmap", "data": data, "raw": True},
                             sheen_color={"type": "checkerboard", "color0": 0.1, "color1": 0.3}))
    params = mi.traverse(bsdf)
    params["diffuse_albedo.data"] = mi.TensorXf(np.full((2, 2, 3), 1.5, dtype=np.float32))
    with pytest.raises(ParameterError, match="kept the previous value of diffuse_albedo$"):
        params.update()
    np.testing.assert_array_equal(np.array(mi.traverse(bsdf)["diffuse_albedo.data"]), np.float32(0.2))
    si = dr.zeros(mi.SurfaceInteraction3f, 1)
    si.uv = mi.Point2f(0.3, 0.3)
    np.testing.assert_allclose(np.array(bsdf.params.textures["diffuse_albedo"].eval(si)), 0.2, rtol=1e-6)
    params["sheen_color.color1.value"] = mi.Float(-1.0)
    # (Mitsuba keeps the keys of a refused update marked as changed: diffuse_albedo again.)
    with pytest.raises(ParameterError, match="kept the previous values of diffuse_albedo, sheen_color$"):
        params.update()
    assert float(mi.traverse(bsdf)["sheen_color.color1.value"][0]) == pytest.approx(0.3)
    # A good update after a refused one is taken.
    params["sheen_color.color1.value"] = mi.Float(0.6)
    params.update()
    assert float(mi.traverse(bsdf)["sheen_color.color1.value"][0]) == pytest.approx(0.6)


# ----------------------------------------------------------------------------------------
# Procedural textures as albedos
# ----------------------------------------------------------------------------------------
def checkerboard(color0, color1):
    return {"type": "checkerboard", "color0": color0, "color1": color1}


def test_a_checkerboard_albedo_is_bounded_by_its_colours():
    """Before the fix any procedural texture was refused (and the message, with the
    texture's several-line str(), was cut at its first line)."""
    bsdf = mi.load_dict(dict(LIGHT_CLOTH, diffuse_albedo=checkerboard({"type": "rgb", "value": [0.2, 0.1, 0.3]}, 0.3)))
    assert bsdf.params.textures["diffuse_albedo"].class_name() == "Checkerboard"
    # Nested: the bound is the largest of every colour.
    load_dict(dict(LIGHT_CLOTH, sheen_color=checkerboard(0.2, checkerboard(0.9, 0.1))))
    with pytest.raises(ParameterError, match="must be <= 1 .*got 1.2 in channel"):
        load_dict(dict(LIGHT_CLOTH, diffuse_albedo=checkerboard(0.2, 0.7)))
    with pytest.raises(ParameterError, match=r"parameter 'sheen_color' .* must lie in \[0, 1\].*\[0.2, 1.5\]"):
        load_dict(dict(LIGHT_CLOTH, sheen_color=checkerboard(0.2, checkerboard(1.5, 0.3))))


@pytest.mark.parametrize("texture,named", [
    ({"type": "mesh_attribute", "name": "vertex_color"}, "MeshAttribute"),
    (checkerboard(0.2, {"type": "mesh_attribute", "name": "vertex_color"}), "Checkerboard > MeshAttribute"),
])
def test_an_albedo_texture_that_cannot_be_bounded_is_a_one_line_error(texture, named):
    """A mesh attribute's values come from the mesh (and it says it does not vary in space,
    so evaluating it anywhere gave a bound of 0): refused, in one line naming it by class."""
    with pytest.raises(ParameterError) as info:
        load_dict(dict(LIGHT_CLOTH, diffuse_albedo=texture))
    message = str(info.value)
    assert message == (f"cloth: parameter 'diffuse_albedo' ({SPECTRUM_PARAMETERS['diffuse_albedo'][1]}): cannot "
                       f"bound the values of texture {named}; use a float, RGB, bitmap or checkerboard")


def test_cli_shows_a_procedural_albedo_error_in_one_line(tmp_path, capsys):
    scene = _cloth_scene_file(tmp_path / "chk.xml",
                              '<texture type="checkerboard" name="diffuse_albedo">',
                              '    <rgb name="color0" value="0.2"/>',
                              '    <texture type="mesh_attribute" name="color1">',
                              '        <string name="name" value="vertex_color"/>',
                              '    </texture>',
                              '</texture>')
    lines = _cli_render_error_lines(scene, tmp_path, capsys)
    assert len(lines) == 1, lines
    assert f"{scene} line 3: " in lines[0] and lines[0].endswith(
        "cannot bound the values of texture Checkerboard > MeshAttribute; use a float, RGB, bitmap or checkerboard")
