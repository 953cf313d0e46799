"""Loading Mitsuba scenes and plugins with mscloth's errors surfaced plainly.

Mitsuba wraps an exception raised inside a plugin constructor into a
RuntimeError that carries the whole Python traceback; we pull our own error's
one-line message back out.
"""
from __future__ import annotations

import re

import mitsuba as mi

from .errors import ClothError, MapsError, ParameterError, PatternError, ResolutionError

_OUR_ERRORS = {cls.__name__: cls for cls in (ClothError, MapsError, ParameterError, PatternError,
                                            ResolutionError)}
_PATTERN = re.compile(r"^(?:[\w.]*\.)?(%s): (.*)$" % "|".join(_OUR_ERRORS), re.MULTILINE)


def unwrap_plugin_error(error: RuntimeError) -> Exception:
    """The mscloth error inside a Mitsuba RuntimeError, or the error itself."""
    match = _PATTERN.search(str(error))
    if match:
        return _OUR_ERRORS[match.group(1)](match.group(2).strip())
    return error


def load_dict(scene: dict):
    """``mi.load_dict`` raising mscloth's own error class for bad cloth input."""
    try:
        return mi.load_dict(scene)
    except RuntimeError as error:
        unwrapped = unwrap_plugin_error(error)
        if unwrapped is error:
            raise
        raise unwrapped from None


def load_file(path: str):
    """``mi.load_file`` with the same error handling."""
    try:
        return mi.load_file(str(path))
    except RuntimeError as error:
        unwrapped = unwrap_plugin_error(error)
        if unwrapped is error:
            raise
        raise unwrapped from None
