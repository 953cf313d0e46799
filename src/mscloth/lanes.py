"""Per-lane helpers shared by the ``cloth`` BSDF, its footprint estimator and the
integrators, in every variant (masks in JIT variants, Python bools and floats in scalar
ones)."""
from __future__ import annotations

import drjit as dr


def logical_not(mask):
    """Logical not, also for the Python bools of scalar variants (where ~ gives an int)."""
    return mask ^ True


def pick(values, index):
    """values[index] per lane, for a short Python list of per-lane values."""
    out = values[0]
    for c in range(1, len(values)):
        out = dr.select(index == c, values[c], out)
    return out
