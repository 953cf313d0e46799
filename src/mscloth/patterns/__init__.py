"""Cloth patterns: weave drafts (named weaves, WIF files) and knits."""
from .draft import Draft
from .named import named_pattern, pattern_names
from .weaves import basket, plain, satin, twill


def read_wif(path):
    """Read a WIF file into a :class:`Draft` (see :mod:`mscloth.patterns.wif`)."""
    from .wif import read_wif as _read_wif

    return _read_wif(path)


__all__ = ["Draft", "basket", "named_pattern", "pattern_names", "plain", "read_wif", "satin", "twill"]
