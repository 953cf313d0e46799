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
