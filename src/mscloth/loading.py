"""Loading Mitsuba scenes and plugins with mscloth's errors surfaced plainly, scenes
checked for what would render worse than it should (:mod:`.scene_checks`), and file paths
in scenes resolved as Mitsuba resolves its own.

Mitsuba wraps an exception raised inside a plugin constructor into a
RuntimeError that carries the whole Python traceback; we pull our own error's
one-line message back out.
"""
from __future__ import annotations

import re

import mitsuba as mi

from .errors import ClothError, MapsError, ParameterError, PatternError, ResolutionError
from .scene_checks import warn_about_scene

_OUR_ERRORS = {cls.__name__: cls for cls in (ClothError, MapsError, ParameterError, PatternError,
                                            ResolutionError)}
_PATTERN = re.compile(r"^(?:[\w.]*\.)?(%s): (.*)$" % "|".join(_OUR_ERRORS), re.MULTILINE)


def unwrap_plugin_error(error: RuntimeError) -> Exception:
    """The mscloth error inside a Mitsuba RuntimeError, or the error itself."""
    match = _PATTERN.search(str(error))
    if match:
        return _OUR_ERRORS[match.group(1)](match.group(2).strip())
    return error


def _ids_in(node, found: set) -> set:
    if isinstance(node, dict):
        if isinstance(node.get("id"), str):
            found.add(node["id"])
        for child in node.values():
            _ids_in(child, found)
    return found


def name_cloths(scene: dict) -> dict:
    """``scene`` with each nested ``cloth`` BSDF that has no ``id`` given its node path as one
    (``floor.bsdf`` inside shape ``floor``), so that its progress lines and warnings say which
    shape it is on (Mitsuba names a nested plugin just ``bsdf``). Ids already in use are
    left alone. Copies only the dictionaries it changes; anything but a scene is returned as is.
    """
    if not isinstance(scene, dict) or scene.get("type") != "scene":
        return scene
    taken = set(scene) | _ids_in(scene, set())

    def visit(node: dict, path: str) -> dict:
        changed = {}
        for key, child in node.items():
            if isinstance(child, dict) and key != "type":
                named = visit(child, f"{path}.{key}")
                if named.get("type") == "cloth" and "id" not in named and f"{path}.{key}" not in taken:
                    named = dict(named, id=f"{path}.{key}")
                    taken.add(named["id"])
                if named is not child:
                    changed[key] = named
        return dict(node, **changed) if changed else node

    changed = {key: visit(node, key) for key, node in scene.items() if isinstance(node, dict)}
    changed = {key: node for key, node in changed.items() if node is not scene[key]}
    return dict(scene, **changed) if changed else scene


def name_xml_cloths(root) -> bool:
    """:func:`name_cloths` for a parsed XML scene (an ElementTree root): each ``cloth``
    ``<bsdf>`` without an id inside a ``<shape id="floor">`` gets ``id="floor.bsdf"``.
    Returns whether it changed anything."""
    taken = {e.get("id") for e in root.iter() if e.get("id")}
    changed = False
    for shape in root.iter("shape"):
        name = f"{shape.get('id')}.bsdf"
        if not shape.get("id") or name in taken:
            continue
        for bsdf in shape.iter("bsdf"):
            if bsdf.get("type") == "cloth" and not bsdf.get("id"):
                bsdf.set("id", name)
                taken.add(name)
                changed = True
                break
    return changed


def load_dict(scene: dict):
    """``mi.load_dict`` raising mscloth's own error class for bad cloth input; nested cloths
    are named after their shapes first (:func:`name_cloths`), and the scene is then checked
    (warnings, :mod:`.scene_checks`)."""
    try:
        loaded = mi.load_dict(name_cloths(scene))
    except RuntimeError as error:
        unwrapped = unwrap_plugin_error(error)
        if unwrapped is error:
            raise
        raise unwrapped from None
    return _checked(loaded)


def load_file(path: str):
    """``mi.load_file`` with the same error handling and checks."""
    try:
        loaded = mi.load_file(str(path))
    except RuntimeError as error:
        unwrapped = unwrap_plugin_error(error)
        if unwrapped is error:
            raise
        raise unwrapped from None
    return _checked(loaded)


def _checked(loaded):
    """``loaded``, after warning about what in it renders worse than it should (at the
    caller of load_dict / load_file)."""
    if isinstance(loaded, mi.Scene):
        warn_about_scene(loaded, stacklevel=3)
    return loaded


def resolve_scene_path(path: str) -> str:
    """A file or directory path named in a scene, found as Mitsuba finds its own (a mesh's
    ``filename``): through the thread's file resolver, which while ``mi.load_file`` loads a
    scene starts with the scene file's directory. A relative path found nowhere comes back
    unchanged (then relative to the working directory)."""
    return str(mi.file_resolver().resolve(path))
