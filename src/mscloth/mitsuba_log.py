"""Mitsuba's log, quietened for a block: its warnings about what mscloth already handles
(a sampler's rounded sample count) would repeat on every call."""
from __future__ import annotations

import contextlib


@contextlib.contextmanager
def errors_only():
    """Mitsuba's log at errors only within the block."""
    import mitsuba as mi

    logger = mi.logger()
    level = logger.log_level()
    logger.set_log_level(mi.LogLevel.Error)
    try:
        yield
    finally:
        logger.set_log_level(level)
