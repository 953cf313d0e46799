"""mscloth: multi-scale surface-based cloth appearance (Zhu et al. 2024) for Mitsuba 3.

Typical use::

    import mitsuba as mi, mscloth
    mi.set_variant(mscloth.default_variant())
    mscloth.register()
    bsdf = mi.load_dict({"type": "cloth", "pattern": "plain"})
"""
import importlib

from .variant import configure_llvm, default_variant, set_default_variant
from .errors import ClothError, MapsError, ParameterError, PatternError

__version__ = "0.1.0"

# Must happen before Dr.Jit starts its LLVM backend; cheap (a few globs).
configure_llvm()


#: Every module the plugins import lazily (constructors, ``traverse``, ``parameters_changed``,
#: renders; ``numpy.random`` on first use): :func:`register` imports them first, since
#: Mitsuba's scene loader builds plugins on several threads at once and first imports racing
#: there failed (``KeyError: 'mscloth.patterns'``, "partially initialized module").
PLUGIN_MODULES = (
    "numpy.random",
    "mscloth.loading", "mscloth.scene_checks", "mscloth.fabrics",
    "mscloth.patterns", "mscloth.patterns.draft", "mscloth.patterns.knit", "mscloth.patterns.named",
    "mscloth.patterns.weaves", "mscloth.patterns.wif",
    "mscloth.maps.builtin", "mscloth.maps.cloth_maps", "mscloth.maps.generate", "mscloth.maps.generator_support",
    "mscloth.maps.knit", "mscloth.maps.woven",
    "mscloth.precompute", "mscloth.precompute.direction_bins", "mscloth.precompute.tables",
    "mscloth.precompute._util",
    "mscloth.bsdf.sky_albedo", "mscloth.cache", "mscloth.atomic",
)

#: Submodules that ``mscloth.NAME`` imports on first use (the README's ``mscloth.loading``),
#: so that ``import mscloth`` stays light: it does not import Mitsuba.
_SUBMODULES = ("fabrics", "loading", "maps", "patterns", "scene_checks")


def __getattr__(name: str):
    if name in _SUBMODULES:
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def register() -> None:
    """Register mscloth's Mitsuba plugins (the ``cloth`` BSDF and the ``clothpath``
    integrator) for the active variant (idempotent); first import every module they
    import lazily (:data:`PLUGIN_MODULES`), so that scenes load safely on many threads."""
    for module in PLUGIN_MODULES:
        importlib.import_module(module)
    from .bsdf.registry import register_plugins
    from .integrators import register_integrators

    register_plugins()
    register_integrators()


def is_rgb_variant(variant: str) -> bool:
    """Whether ``variant`` is one mscloth renders: RGB, not polarized (``scalar_rgb``,
    ``llvm_ad_rgb``, ``cuda_ad_rgb``, ...)."""
    parts = variant.split("_")
    return "rgb" in parts and "polarized" not in parts


def setup_mitsuba(variant: str | None = None) -> str:
    """Make ``variant`` active (default: the active one, else :func:`default_variant`),
    register mscloth's plugins for it and return it: the one set-up of the command line and
    of :mod:`mscloth.evaluation`."""
    import mitsuba as mi

    from .variant import variant_unavailable

    # The cloth BSDF's albedos, maps and tables are RGB: a mono or spectral variant fails
    # deep in Dr.Jit, a polarized one's Stokes output is not what the energy checks expect.
    rgb = [v for v in mi.variants() if is_rgb_variant(v)]
    if variant is None:
        variant = set_default_variant()
        if not is_rgb_variant(variant):  # one the caller made active
            raise ClothError(f"mscloth renders RGB variants only: {', '.join(rgb)}; the active variant "
                             f"is {variant!r}")
    else:
        if not is_rgb_variant(variant):
            raise ClothError(f"mscloth renders RGB variants only: {', '.join(rgb)}; got {variant!r}")
        if variant not in mi.variants():
            raise ClothError(f"unknown variant {variant!r}: expected one of {', '.join(rgb)}")
        why = variant_unavailable(variant)
        if why is not None:
            raise ClothError(f"variant {variant!r} cannot run here: {why}")
        try:
            mi.set_variant(variant)
        except ImportError as error:  # a backend that fails in a way the check above missed
            lines = str(error).strip().splitlines() or [type(error).__name__]
            raise ClothError(f"variant {variant!r} cannot run here: {lines[0]}") from None
    register()
    return variant


__all__ = [
    "ClothError", "MapsError", "ParameterError", "PatternError",
    "configure_llvm", "default_variant", "register", "set_default_variant", "setup_mitsuba", "__version__",
]
