"""Named shading state of the ``cloth`` BSDF, shared by its fibre-level BSDF
(:mod:`.fibre_bsdf`), its footprint estimator (:mod:`.footprint_estimator`) and the plugin
(:mod:`.cloth`).

Plain dataclasses of Dr.Jit values (Python floats and bools in scalar variants): they are
built and read inside one shading call, never carried through a symbolic loop, so they
need no ``DRJIT_STRUCT``; Dr.Jit 1.x treats dataclasses as PyTrees where one must cross.
Every direction here is in the *mirrored* frame, where the viewer is above the surface
(decision "Two-sided cloth: mirror through the surface").
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import drjit as dr
import mitsuba as mi

#: The albedo parameters of the yarn lobes, which the yarn colour multiplies.
YARN_LOBE_ALBEDOS = ("specular_albedo", "specular_transmittance", "diffuse_albedo", "diffuse_transmittance")


@dataclass
class LobeAlbedos:
    """The lobes' albedo parameters at a shading point (textures evaluated), before or
    after the yarn colour (:meth:`with_yarn_albedo`)."""

    specular_albedo: Any
    specular_transmittance: Any
    diffuse_albedo: Any
    diffuse_transmittance: Any
    sheen_color: Any

    def with_yarn_albedo(self, yarn_albedo) -> LobeAlbedos:
        """The albedos with the yarn colour applied (every yarn lobe; not the sheen)."""
        return dataclasses.replace(self, **{name: getattr(self, name) * yarn_albedo for name in YARN_LOBE_ALBEDOS})


def max_channel(c):
    """The largest of an RGB colour's three channels."""
    return dr.maximum(dr.maximum(c[0], c[1]), c[2])


@dataclass
class ViewFrame:
    """What a shading point knows before any texel is read: the viewer in the mirrored
    frame, the lobe albedos, the fuzz's transmittance towards the viewer and the shading
    point in texel coordinates of the tile."""

    #: Whether the viewer is below the surface (the frame is mirrored through it).
    flip: Any
    #: -1 where flipped, else 1: multiplies z to go between the frames.
    sign: Any
    #: The direction to the viewer (mirrored frame: z >= 0).
    wi: Any
    #: The lobes' albedo parameters, without the yarn colour.
    k: LobeAlbedos
    #: T_sheen(i): what of the light towards the viewer crosses the fuzz.
    t_sheen_i: Any
    #: Texel coordinates of si.uv (after the parallax shift, if on).
    x: Any
    y: Any
    active: Any
    #: The camera sample's offset from its pixel centre along si.duv_dx, si.duv_dy (each
    #: in [-1/2, 1/2); below: not known); None outside ``clothpath``'s first hits.
    pixel_offset: Any = None
    #: The filter over the pixel that places the camera sample: ``box`` (the offset is
    #: where it lies in the pixel) or ``tent`` (``clothpath``'s ``uv_filter``: box x tent).
    pixel_filter: str = "box"

    def mirror(self, wo):
        """``wo`` in the mirrored frame (where the viewer is above), or back."""
        return mi.Vector3f(wo.x, wo.y, self.sign * wo.z)


@dataclass
class Texel:
    """The fibre-level state of one texel seen from ``frame``."""

    frame: ViewFrame
    #: The fibre tangent (mirrored frame).
    tangent: Any
    #: Yarn coverage I of the texel (0 in a gap).
    yarn: Any
    #: The lobe albedos times the texel's yarn colour.
    k: LobeAlbedos
    #: The texel's indices in the tile.
    ix: Any
    iy: Any
    #: Visibility bits of the texel's height field, its cluster, V(p, i) and its
    #: cluster's mean v_c(i) (filled in where visibility is used).
    vis: Any = None
    cluster: Any = None
    v_i: Any = None
    cvis_i: Any = None
    #: The texel's yarn colour (RGB).
    color: Any = None

    @property
    def wi(self):
        return self.frame.wi

    @property
    def flip(self):
        return self.frame.flip

    @property
    def t_sheen_i(self):
        return self.frame.t_sheen_i
