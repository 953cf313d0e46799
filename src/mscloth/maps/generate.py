"""``generate_maps``: any pattern (Draft, drawdown, knit, name or WIF path) -> ClothMaps."""
from __future__ import annotations

import inspect
import os

import numpy as np

from ..errors import ParameterError
from ..patterns.draft import Draft
from ..patterns.named import named_pattern
from .cloth_maps import ClothMaps
from .woven import woven_maps

DEFAULT_RESOLUTION = 256


def _generator(pattern):
    if isinstance(pattern, (Draft, np.ndarray, list)):
        return woven_maps
    from ..patterns.knit import KnitPattern

    if isinstance(pattern, KnitPattern):
        from .knit import knit_maps

        return knit_maps
    raise ParameterError(f"generate_maps: expected a Draft, a drawdown, a KnitPattern, a pattern "
                         f"name or a .wif path, got {type(pattern).__name__}")


def generator_parameters(pattern) -> set[str]:
    """The parameters (besides pattern and resolution) that ``pattern``'s map generator takes."""
    return set(inspect.signature(_generator(pattern)).parameters) - {"pattern", "resolution"}


def generate_maps(pattern, resolution=DEFAULT_RESOLUTION, **params) -> ClothMaps:
    """Seamless fibre-level maps of one tile of ``pattern``.

    ``pattern``: a :class:`~mscloth.patterns.Draft`, a drawdown array, a
    :class:`~mscloth.patterns.knit.KnitPattern`, a pattern name (``twill-2-1``, ``jersey``...)
    or a ``.wif`` path. ``resolution``: texels along u (the height follows the tile's
    aspect) or (H, W). ``params`` go to the woven or knit generator (see
    :func:`~mscloth.maps.woven.woven_maps` and :func:`~mscloth.maps.knit.knit_maps`);
    one that the generator does not take is an error naming it.
    """
    if isinstance(pattern, (str, os.PathLike)):
        pattern = named_pattern(os.fspath(pattern))
    generator = _generator(pattern)
    accepted = inspect.signature(generator).parameters
    unknown = sorted(set(params) - set(accepted))
    if unknown:
        allowed = ", ".join(name for name in accepted if name not in ("pattern", "resolution"))
        raise ParameterError(f"{generator.__name__} does not take {', '.join(unknown)}; "
                             f"its parameters are: {allowed}")
    return generator(pattern, resolution, **params)
