"""Bad input raises a clear error naming the parameter and what was expected."""
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


def test_cli_names_a_misspelled_parameter_in_a_scene_file(tmp_path, capsys):
    from mscloth.cli import main

    scene = tmp_path / "typo.xml"
    scene.write_text('<scene version="3.0.0">\n'
                     '    <shape type="rectangle">\n'
                     '        <bsdf type="cloth">\n'
                     '            <float name="sheen_thicknes" value="0.3"/>\n'
                     '        </bsdf>\n'
                     '    </shape>\n'
                     '</scene>\n')
    assert main(["render", str(scene), "--out", str(tmp_path / "x.exr")]) == 2
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(lines) == 1, lines
    assert f"{scene} line 3: " in lines[0] and "'sheen_thicknes'" in lines[0] and "'sheen_thickness'" in lines[0]
    # Another plugin's misspelling: Mitsuba's message, with the name it lists on its next line.
    scene.write_text(scene.read_text().replace('type="cloth"', 'type="diffuse"').replace(
        'float name="sheen_thicknes" value="0.3"', 'rgb name="reflectanc" value="0.3"'))
    assert main(["render", str(scene), "--out", str(tmp_path / "x.exr")]) == 2
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].endswith('of type "diffuse": reflectanc'), lines
    assert not (tmp_path / "x.exr").exists()
