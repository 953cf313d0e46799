"""The six lobes of the ``cloth`` BSDF: their component indices (the order of
``m_components``) and names, shared by the plugin, its footprint estimator and its
sampling calibration."""

SHEEN, SPECULAR_REFLECTION, DIFFUSE_REFLECTION, SPECULAR_TRANSMISSION, DIFFUSE_TRANSMISSION, GAP = range(6)
LOBE_NAMES = ("sheen", "specular_reflection", "diffuse_reflection",
              "specular_transmission", "diffuse_transmission", "gap")


def lobe_types() -> tuple:
    """Mitsuba's type flag of each lobe, in component order."""
    import mitsuba as mi
    f = mi.BSDFFlags
    return (f.GlossyReflection, f.GlossyReflection, f.DiffuseReflection,
            f.GlossyTransmission, f.DiffuseTransmission, f.DeltaTransmission)


def component_flags() -> list:
    """Each component's flags (``m_components``): its type, both sides (the cloth is thin
    and two-sided), and spatially varying for all but the sheen, which the maps leave
    alone."""
    import mitsuba as mi
    both_sides = mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide
    varying = mi.BSDFFlags.SpatiallyVarying
    return [t | both_sides if c == SHEEN else t | both_sides | varying for c, t in enumerate(lobe_types())]


def enabled_lobes(ctx) -> list:
    """Whether each of the six lobes is enabled by ``ctx`` (its type mask, component)."""
    types = lobe_types()
    return [ctx.is_enabled(types[c], c) for c in range(6)]
