"""Warnings for scenes that load and render, but not as they should with ``cloth``.

Checked once a scene is loaded by :mod:`mscloth.loading` or ``mscloth render``, for each
shape whose BSDF is ``cloth`` or nests one (in ``blendbsdf``, ``mask``, ``bumpmap``...):

* a mesh without UVs under ``cloth``: Mitsuba then gives each triangle barycentric UVs, so
  every triangle holds a squeezed copy of the tile and the weave blurs to nothing. Analytic
  shapes (sphere, disk, cylinder, rectangle) have parametric UVs.
* a mesh under ``cloth`` with non-finite UVs (NaN or infinite in its file): the cloth is
  shaded there as at uv (0, 0) (``cloth`` guards its table reads against them).
* a multi-scale ``cloth`` under an integrator that hands BSDFs no pixel footprints
  (Mitsuba's ``path`` drops ray differentials): it is then shaded at points, with about 4x
  the noise of ``clothpath``.

One warning per kind of problem and scene (:class:`SceneWarning`), naming the shapes.
"""
from __future__ import annotations

import re
import warnings

import mitsuba as mi
import numpy as np

from .plugin_registry import registered_class

#: Shapes named in one warning before "and N more".
MAX_NAMED = 5


class SceneWarning(UserWarning):
    """A scene renders, but worse than it should (see :mod:`mscloth.scene_checks`)."""


def shape_name(shape, index: int) -> str:
    """A shape's id, else its file's name (meshes), else its kind and index in the scene."""
    if shape.id():
        return repr(shape.id())
    # Meshes print the name of the file they were loaded from; there is no accessor.
    match = re.search(r'\bname = "([^"]*)"', str(shape))
    if match and match.group(1):
        return repr(match.group(1))
    return f"{shape.class_name()} #{index}"


def _listed(names: list[str]) -> str:
    shown = ", ".join(names[:MAX_NAMED])
    return shown + (f" and {len(names) - MAX_NAMED} more" if len(names) > MAX_NAMED else "")


def _hands_footprints(integrator) -> bool:
    """Whether ``integrator`` gives BSDFs pixel footprints: ``clothpath``, or an integrator
    that nests one (``aov``; Mitsuba shows nested integrators only in its text form)."""
    clothpath = registered_class("clothpath")
    if clothpath is not None and isinstance(integrator, clothpath):
        return True
    return "ClothPathIntegrator[" in str(integrator)


def _integrator_name(integrator) -> str:
    """``PathIntegrator``, ``VolumetricPathIntegrator``...: the head of its text form."""
    return str(integrator).split("[", 1)[0].strip() or integrator.class_name()


def cloths_in(bsdf, cloth: type) -> list:
    """The ``cloth`` BSDFs (instances of ``cloth``) that ``bsdf`` is or nests, at any depth
    (``blendbsdf``, ``mask``, ``bumpmap``... hand theirs to ``traverse``)."""
    found, seen = [], set()

    class Nested(mi.TraversalCallback):
        def put(self, name, value, flags, cpptype=None):
            if isinstance(value, mi.BSDF):
                visit(value)

    def visit(node):
        if node is None or node in seen:
            return
        seen.add(node)
        if isinstance(node, cloth):
            found.append(node)
        else:
            node.traverse(Nested())

    visit(bsdf)
    return found


def scene_problems(scene) -> list[str]:
    """What renders worse than it should in ``scene``: one message per kind of problem."""
    cloth = registered_class("cloth")
    if cloth is None:
        return []
    without_uvs, non_finite, multiscale = [], [], []
    for index, shape in enumerate(scene.shapes()):
        cloths = cloths_in(shape.bsdf(), cloth)
        if not cloths:
            continue
        if shape.is_mesh() and not shape.has_vertex_texcoords():
            without_uvs.append(shape_name(shape, index))
        elif shape.is_mesh():
            bad = int(np.count_nonzero(~np.isfinite(np.asarray(shape.vertex_texcoords_buffer()))))
            if bad:
                non_finite.append(f"{shape_name(shape, index)} ({bad} non-finite)")
        if any(c.footprint_shading for c in cloths):
            multiscale.append(shape_name(shape, index))
    problems = []
    if without_uvs:
        problems.append(
            f"cloth on {_listed(without_uvs)}, a mesh without UV coordinates: Mitsuba gives each "
            "triangle its own barycentric UVs and the weave blurs to nothing; give the mesh UVs")
    if non_finite:
        problems.append(
            f"cloth on {_listed(non_finite)}, a mesh with NaN or infinite UV coordinates: the cloth is "
            "shaded there as at uv (0, 0); fix the mesh's UVs")
    # No integrator in the scene: the one given to mi.render is not known here.
    integrator = scene.integrator()
    if multiscale and integrator is not None and not _hands_footprints(integrator):
        problems.append(
            f"multi-scale cloth on {_listed(multiscale)} under {_integrator_name(integrator)}, which hands "
            "BSDFs no pixel footprints: it is shaded at points, with about 4x the noise of clothpath; use the "
            "clothpath integrator (or multiscale false for fibre-level cloth)")
    return problems


def warn_about_scene(scene, stacklevel: int = 1) -> None:
    """Warn (:class:`SceneWarning`) about each of :func:`scene_problems`; ``stacklevel`` 1
    points the warning at the caller of this function, as for ``warnings.warn``."""
    for message in scene_problems(scene):
        warnings.warn(f"mscloth: {message}", SceneWarning, stacklevel=stacklevel + 1)
