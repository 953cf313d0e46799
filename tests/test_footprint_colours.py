"""Footprints over yarns of different colours against brute force (issue 20).

Denim's indigo warp and ecru weft: which yarn a texel belongs to sets its colour and also
its tangent, so its highlight and its visibility. The footprint's mean colour times the
mean of the rest is then not the mean of the product (11-21% off in the red channel at
grazing and transmitted pairs over a tile and more, before the residual texels carried
their own colour). Brute force is the Monte Carlo mean of the fibre-level BSDF over the
same footprint (:mod:`mscloth.validation`); red is the channel where the yarns differ most
(0.02 against 0.7)."""
import numpy as np
import pytest

import mitsuba as mi

import mscloth
from mscloth import validation
from mscloth.scenes.builtin import DENIM_MAPS, scene_maps

mscloth.register()

#: Texels per side of the denim maps' tile (four threads of 16 texels).
TILE = DENIM_MAPS["resolution"]

#: (wi, wo): grazing across and along the warp, a low sun seen from above, transmission.
PAIRS = {
    "grazing-across": ([0.95, 0.1, 0.3], [-0.9, 0.2, 0.35]),
    "grazing-along": ([0.1, 0.95, 0.3], [0.2, -0.9, 0.35]),
    "low-sun": ([0.0, -0.6, 0.8], [0.5, 0.83, 0.26]),
    "transmission": ([0.2, 0.4, 0.89], [-0.3, -0.2, -0.93]),
}

#: The stated approximation of the footprint form (relative), beside 5 standard errors.
APPROXIMATION = 0.02


@pytest.fixture(scope="module")
def denim_maps(tmp_path_factory):
    return scene_maps("denim_maps", DENIM_MAPS, tmp_path_factory.mktemp("maps"))


def denim(maps: str, roughness: float) -> dict:
    """The `denim` scene's cloth (uv_scale 1) at ``roughness``."""
    return {"type": "cloth", "pattern": maps, "roughness": roughness, "specular_albedo": 0.35,
            "specular_transmittance": 0.1, "diffuse_albedo": 0.5, "diffuse_transmittance": 0.05,
            "sheen_thickness": 0.15}


def test_the_denim_maps_have_two_yarn_colours(denim_maps):
    """The premise: the tile's yarns differ in colour (no uniform yarn colour)."""
    bsdf = mi.load_dict(denim(denim_maps, 0.33))
    assert bsdf.fibre.tile.uniform_yarn_colour is None


@pytest.mark.parametrize("roughness", [0.1, 0.33])
@pytest.mark.parametrize("half", [24.0, 1.5 * TILE])
@pytest.mark.parametrize("pair", list(PAIRS))
def test_footprints_over_two_yarn_colours_match_brute_force(denim_maps, roughness, half, pair):
    """Shiny (exact corners, 4 x 4 residual texels, a finer grid for large probes) and rough
    (rounded corners, 2 x 2) footprints of 48^2 texels and of 3 tiles."""
    params = denim(denim_maps, roughness)
    bsdf = mi.load_dict(params)
    wi, wo = PAIRS[pair]
    uv = [0.3, 0.55]
    si = validation.footprint_interaction(40000, uv, half, TILE, wi)
    ms, ms_err = validation.shading_expectation(bsdf, si, wo)
    bf, bf_err = validation.brute_force(params, uv, half, TILE, wi, wo, n=60000)
    tolerance = 5.0 * np.hypot(ms_err, bf_err) + APPROXIMATION * abs(bf)
    assert abs(ms - bf) <= tolerance, (pair, half, ms, bf, tolerance)
