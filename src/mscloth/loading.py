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

from .errors import ClothError, MapsError, ParameterError, PatternError
from .scene_checks import warn_about_scene

_OUR_ERRORS = {cls.__name__: cls for cls in (ClothError, MapsError, ParameterError, PatternError)}
_PATTERN = re.compile(r"^(?:[\w.]*\.)?(%s): (.*)$" % "|".join(_OUR_ERRORS), re.MULTILINE)


def unwrap_plugin_error(error: RuntimeError) -> Exception:
    """The mscloth error inside a Mitsuba RuntimeError, or the error itself."""
    match = _PATTERN.search(str(error))
    if match:
        return _OUR_ERRORS[match.group(1)](match.group(2).strip())
    return error


def load_dict(scene: dict):
    """``mi.load_dict`` raising mscloth's own error class for bad cloth input; a scene is
    then checked (warnings, :mod:`.scene_checks`)."""
    try:
        loaded = mi.load_dict(scene)
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
