"""The six lobes of the ``cloth`` BSDF: their component indices (the order of
``m_components``) and names, shared by the plugin and its sampling calibration."""

SHEEN, SPECULAR_REFLECTION, DIFFUSE_REFLECTION, SPECULAR_TRANSMISSION, DIFFUSE_TRANSMISSION, GAP = range(6)
LOBE_NAMES = ("sheen", "specular_reflection", "diffuse_reflection",
              "specular_transmission", "diffuse_transmission", "gap")
