"""The ``cloth`` BSDF's parameter ranges and its energy bound, without Mitsuba: the plugin
validates what it reads with them (:mod:`.bsdf.parameters`), and so does a fabric preset,
whose values the plugin takes as they are (:mod:`.fabrics`)."""
from __future__ import annotations

import math

import numpy as np

#: (name, default, lowest, highest, lowest allowed itself?) of the scalar parameters.
FLOAT_PARAMETERS = {
    # name: (default, low, high, low_inclusive, meaning)
    "uv_scale": (1.0, 0.0, math.inf, False, "pattern tiles per UV unit"),
    "uv_scale_v": (0.0, 0.0, math.inf, True, "pattern tiles per UV unit along v (0: from uv_scale and the tile's aspect)"),
    "uv_unit": (0.0, 0.0, 1e6, True, "length of one UV unit in metres, for UVs in physical units (0: uv_scale "
                                     "counts tiles per UV unit; 1 with a fabric)"),
    "roughness": (0.3, 0.0, 1.0, False, "fibre SGGX roughness alpha (alpha^2 along the fibre)"),
    "thickness": (2.0, 0.0, 1e3, False, "optical thickness T of the yarn layer"),
    "sheen_roughness": (0.5, 0.0, 1.0, False, "roughness of the fuzz fibres"),
    "sheen_thickness": (0.2, 0.0, 1e3, True, "optical thickness of the fuzz layer (0: no sheen)"),
}

#: Spectrum parameters (float, RGB or texture), all within [0, 1].
SPECTRUM_PARAMETERS = {
    "specular_albedo": (0.4, "albedo k_rs of specular fibre reflection"),
    "specular_transmittance": (0.2, "albedo k_ts of specular fibre transmission"),
    "diffuse_albedo": (0.4, "albedo k_rd of diffuse (multiply scattered) reflection"),
    "diffuse_transmittance": (0.1, "albedo k_td of diffuse transmission"),
    "sheen_color": (0.5, "albedo of the fuzz fibres"),
}

#: The spectrum parameters in the energy bound (:func:`reflected_bound`).
ENERGY_PARAMETERS = ("diffuse_albedo", "diffuse_transmittance", "specular_albedo", "specular_transmittance")


def reflected_bound(diffuse_albedo, diffuse_transmittance, specular_albedo, specular_transmittance):
    """The most light the cloth can send back of what it receives (numbers, or per-channel
    arrays): single scattering returns at most max(k_rs, k_ts) (its R + T < 1), the diffuse
    lobes k_rd + k_td. Above 1 (the checks allow 1e-6) the cloth would create light."""
    return diffuse_albedo + diffuse_transmittance + np.maximum(specular_albedo, specular_transmittance)
