"""Errors mscloth raises for bad input. Each names what was wrong and what was expected."""


class ClothError(ValueError):
    """Base class of every error mscloth raises for bad input."""


class ParameterError(ClothError):
    """A plugin parameter is missing, of the wrong type or out of range."""


class PatternError(ClothError):
    """A pattern name, draft or pattern file could not be turned into cloth maps."""


class MapsError(ClothError):
    """A cloth-maps directory or array is missing, malformed or inconsistent."""
