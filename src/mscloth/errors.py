"""Errors mscloth raises for bad input. Each names what was wrong and what was expected."""


class ClothError(ValueError):
    """Base class of every error mscloth raises for bad input."""


class ParameterError(ClothError):
    """A plugin parameter is missing, of the wrong type or out of range."""


class ResolutionError(ParameterError):
    """A tile resolution a pattern's maps cannot have. ``low``, ``high``: the texels along u
    that would do (None when an exact (H, W) was asked for); ``reason``: what bounds them."""

    def __init__(self, message: str, low: int | None = None, high: int | None = None, reason: str = ""):
        super().__init__(message)
        self.low, self.high, self.reason = low, high, reason


class PatternError(ClothError):
    """A pattern name, draft or pattern file could not be turned into cloth maps."""


class MapsError(ClothError):
    """A cloth-maps directory or array is missing, malformed or inconsistent."""
