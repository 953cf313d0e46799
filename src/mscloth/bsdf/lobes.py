"""The six lobes of the ``cloth`` BSDF: their component indices (the order of
``m_components``) and names, shared by the plugin, its footprint estimator and its
sampling calibration."""

SHEEN, SPECULAR_REFLECTION, DIFFUSE_REFLECTION, SPECULAR_TRANSMISSION, DIFFUSE_TRANSMISSION, GAP = range(6)
LOBE_NAMES = ("sheen", "specular_reflection", "diffuse_reflection",
              "specular_transmission", "diffuse_transmission", "gap")


def with_yarn_albedo(k, yarn_albedo):
    """The lobe albedos with the yarn colour applied (every yarn lobe; not sheen)."""
    k = dict(k)
    for name in ("specular_albedo", "specular_transmittance", "diffuse_albedo", "diffuse_transmittance"):
        k[name] = k[name] * yarn_albedo
    return k
