"""The ``mscloth`` command line."""
from __future__ import annotations

import argparse
import inspect
import os
import re
import sys
import time
import warnings
from pathlib import Path

from . import __version__, setup_mitsuba
from .errors import ClothError, ResolutionError
from .scenes.names import SCENE_NAMES
from .scenes.pixel_sampler import DEFAULT_PIXEL_SAMPLER, PIXEL_SAMPLERS


def _positive_int(low: int, high: int):
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}")
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"expected an integer in [{low}, {high}], got {value}")
        return value
    return parse


def _maps_res(text: str) -> int:
    """``maps --res``: up to the generators' largest tile side (imported here: it brings NumPy)."""
    from .maps.generator_support import MAX_RESOLUTION

    return _positive_int(8, MAX_RESOLUTION)(text)


def cmd_demo(args) -> int:
    import mitsuba as mi

    from .atomic import check_writable
    from .loading import load_dict
    from .render import KernelCompilation, render_progressive, throughput_text, write_images
    from .scenes.demo import demo_scene

    variant = setup_mitsuba(args.variant)
    out = Path(args.out)
    exr = out / "demo.exr"
    # --out is a folder of the demo's own: its demo.exr/png are replaced on every run
    # (`make demo` twice), unlike render's --out, which names the user's file.
    check_writable(out, target=exr)
    scene = load_dict(demo_scene(resolution=args.res))
    spp = _samples_taken(scene, args.spp)
    print(f"mscloth demo: {args.res}x{args.res}, {spp} spp, variant {variant}")
    started = time.perf_counter()
    with KernelCompilation() as compiling:
        image = render_progressive(scene, spp, label="demo")
    seconds = time.perf_counter() - started
    exr, png = write_images(image, exr)
    print(f"wrote {exr} and {png}: {throughput_text(args.res * args.res * spp, seconds, compiling.seconds)}")
    return 0


def _samples_taken(scene, spp: int) -> int:
    """The samples per pixel the scene's sampler takes for ``--spp`` (rounded up by some
    samplers), with one warning where it differs."""
    from .render import samples_taken

    taken = samples_taken(scene, spp)
    if taken != spp:
        name = scene.sensors()[0].sampler().class_name()
        warnings.warn(f"the scene's sampler ({name}) takes {taken} samples per pixel, not --spp {spp}: "
                      f"rendering {taken}", UserWarning, stacklevel=2)
    return taken


def _writable_outputs(*paths: Path) -> None:
    """ClothError unless each of ``paths`` can be written as a file: before the work that
    makes them, naming the user's path (not a temporary file beside it). Makes no folder:
    a command that then fails leaves nothing behind."""
    from .atomic import check_writable

    for path in paths:
        if path.is_dir():
            raise ClothError(f"cannot write {path}: it is a directory")
        parent = path.parent
        while not parent.exists() and parent != parent.parent:
            parent = parent.parent
        if not parent.is_dir():
            raise ClothError(f"cannot write {path}: {parent} is a file, not a directory")
        check_writable(parent, target=path)  # the folders below it are made as it is written


def _resolution_arg(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, e.g. 640x360, got {text!r}")
    if not (8 <= w <= 16384 and 8 <= h <= 16384):
        raise argparse.ArgumentTypeError(f"width and height must be in [8, 16384], got {w}x{h}")
    return w, h


def _swatch_options(args, scene: str) -> dict:
    """The swatch scene's --fabric, --view and --light that were given; an error for
    another scene."""
    options = {name: value for name, value in (("fabric", args.fabric), ("view", args.view),
                                                 ("light", args.light)) if value is not None}
    if options and scene != "swatch":
        flag, value = next(iter(options.items()))
        raise ClothError(f"--{flag} applies to the swatch scene only "
                         f"(mscloth {args.command} swatch --{flag} {value}), not to {scene!r}")
    return options


def _scene_resolution(name: str, res) -> tuple[int, int]:
    """``--res``, else the built-in scene's own width and height (its builder's defaults):
    ``render`` and ``scene`` frame it alike (the fov is horizontal)."""
    from .scenes.builtin import SCENES

    if res:
        return res
    parameters = inspect.signature(SCENES[name]).parameters
    return parameters["width"].default, parameters["height"].default


def load_scene_file(path: Path, res):
    """Load a Mitsuba XML scene, overriding its film's width/height when ``res`` is given and
    naming its cloths after their shapes (:func:`mscloth.loading.name_xml_cloths`)."""
    import xml.etree.ElementTree as ET

    import mitsuba as mi

    from .loading import name_xml_cloths, unwrap_plugin_error
    from .scene_checks import warn_about_scene

    if not path.is_file():
        raise ClothError(f"scene file {path} does not exist")
    try:
        tree = ET.parse(path)
        named = name_xml_cloths(tree.getroot())
        if res is None and not named:
            scene = mi.load_file(str(path))
            warn_about_scene(scene)
            return scene
        if res is not None:
            films = tree.getroot().findall(".//film")
            if not films:
                raise ClothError(f"{path}: no <film> to set --res on")
            for film in films:
                for key, value in (("width", res[0]), ("height", res[1])):
                    node = film.find(f"integer[@name='{key}']")
                    if node is None:
                        node = ET.SubElement(film, "integer", name=key)
                    node.set("value", str(value))
        # The scene's directory first while it loads, as mi.load_file does.
        previous = mi.file_resolver()
        resolver = mi.FileResolver(previous)
        resolver.prepend(str(path.parent.resolve()))
        mi.set_file_resolver(resolver)
        try:
            scene = mi.load_string(ET.tostring(tree.getroot(), encoding="unicode"))
        finally:
            mi.set_file_resolver(previous)
    except ET.ParseError as error:
        raise ClothError(f"{path}: not valid XML: {error}") from None
    except RuntimeError as error:
        text = str(error)
        unwrapped = unwrap_plugin_error(error)
        if unwrapped is not error:
            # The line is the file's only when it was loaded as it is (not re-serialised for --res).
            where = re.search(r"\(line (\d+), col \d+\)", text) if res is None else None
            raise type(unwrapped)(f"{path}{f' line {where.group(1)}' if where else ''}: {unwrapped}") from None
        lines = [line for line in text.splitlines() if line.strip()]
        # Mitsuba lists unreferenced (e.g. misspelled) properties on the lines after the first.
        names = re.findall(r'^\s*- \w+ "([^"]+)"', text, re.MULTILINE)
        listed = f" {', '.join(names)}" if names and lines[0].rstrip().endswith(":") else ""
        raise ClothError(f"cannot load {path}: {lines[0] if lines else error}{listed}") from None
    warn_about_scene(scene)
    return scene


def cmd_render(args) -> int:
    import mitsuba as mi

    from .loading import load_dict
    from .render import KernelCompilation, render_progressive, throughput_text, write_images
    from .scenes.builtin import SCENES, builtin_scene
    from .scenes.pixel_sampler import set_pixel_sampler

    out = Path(args.out) if args.out else Path("out") / f"{Path(args.scene).stem}.exr"
    if out.suffix.lower() != ".exr":
        raise ClothError(f"--out must name an .exr file (a .png is written beside it), got {out}")
    if args.scene not in SCENES and not args.scene.lower().endswith(".xml"):
        raise ClothError(f"unknown scene {args.scene!r}: expected one of {', '.join(SCENES)} or a .xml file")
    if args.scene not in SCENES and not Path(args.scene).is_file():
        raise ClothError(f"scene file {args.scene} does not exist")
    if args.sampler and args.scene not in SCENES:
        raise ClothError("--sampler applies to the built-in scenes; a scene file names its own sampler")
    if not args.force:
        existing = [p for p in (out, out.with_suffix(".png")) if p.exists()]
        if existing:
            raise ClothError(f"{existing[0]} exists; pass --force to overwrite")
    options = _swatch_options(args, args.scene)
    variant = setup_mitsuba(args.variant)
    _writable_outputs(out, out.with_suffix(".png"))  # before the render, not after it
    # Loading makes each cloth's maps, builds (or reads) its tables and compiles its
    # calibration kernels: on a first run, much of the time to the first picture
    # (bench/first_picture.py). Their compilation is not split out: Mitsuba constructs
    # plugins on its own threads, and Dr.Jit's kernel history flag is per thread.
    loading_started = time.perf_counter()
    if args.scene in SCENES:
        w, h = _scene_resolution(args.scene, args.res)
        scene_dict = builtin_scene(args.scene, w, h, **options)
        if args.sampler:
            set_pixel_sampler(scene_dict, args.sampler)
        scene = load_dict(scene_dict)
    else:
        scene = load_scene_file(Path(args.scene), args.res)
    loading_seconds = time.perf_counter() - loading_started
    w, h = scene.sensors()[0].film().size()
    spp = _samples_taken(scene, args.spp)
    print(f"mscloth render: {args.scene}, {w}x{h}, {spp} spp, variant {variant} "
          f"(loaded in {loading_seconds:.2f} s)", flush=True)
    started = time.perf_counter()
    with KernelCompilation() as compiling:
        image = render_progressive(scene, spp, label="render")
    seconds = time.perf_counter() - started
    exr, png = write_images(image, out)
    print(f"wrote {exr} and {png}: {throughput_text(w * h * spp, seconds, compiling.seconds)}")
    return 0


def _relative_to_xml(node, folder: Path) -> None:
    """Rewrite the files a scene dictionary names relative to ``folder`` (the XML's): meshes,
    ``cloth`` maps directories made in it, and ``.json`` fabric files (given relative to the
    working directory, which loading the XML does not look in)."""
    if not isinstance(node, dict):
        return
    if node.get("type") == "ply":
        node["filename"] = os.path.relpath(Path(node["filename"]).resolve(), folder)
    if node.get("type") == "cloth":
        pattern = node.get("pattern")
        if isinstance(pattern, (str, os.PathLike)) and Path(pattern).is_absolute() \
                and Path(pattern).resolve().is_relative_to(folder):
            node["pattern"] = os.path.relpath(Path(pattern).resolve(), folder)
        fabric = node.get("fabric")
        if isinstance(fabric, (str, os.PathLike)) and os.fspath(fabric).lower().endswith(".json"):
            node["fabric"] = os.path.relpath(Path(fabric).resolve(), folder)
    for value in node.values():
        _relative_to_xml(value, folder)


def cmd_scene(args) -> int:
    from .scenes.builtin import SCENES
    from .scenes.xml_export import scene_to_xml

    out = Path(args.out)
    if args.name not in SCENES:
        raise ClothError(f"unknown scene {args.name!r}: expected one of {', '.join(SCENES)}")
    if out.suffix.lower() != ".xml":
        raise ClothError(f"--out must name an .xml file, got {out}")
    if out.exists() and not args.force:
        raise ClothError(f"{out} exists; pass --force to overwrite")
    setup_mitsuba(args.variant)
    _writable_outputs(out)
    w, h = _scene_resolution(args.name, args.res)
    # Meshes and cloth maps next to the XML, referenced relative to it (Mitsuba resolves a
    # scene's paths against its file's folder first), so the folder can be moved.
    folder = out.parent.resolve()
    accepted = inspect.signature(SCENES[args.name]).parameters
    kwargs = {key: folder / sub for key, sub in (("mesh_dir", "meshes"), ("maps_dir", "maps")) if key in accepted}
    options = _swatch_options(args, args.name)
    scene = SCENES[args.name](w, h, **kwargs, **options)
    _relative_to_xml(scene, folder)
    from .atomic import atomic_write

    atomic_write(out, lambda f: f.write(scene_to_xml(scene).encode()))
    print(f"wrote {out} (render it with: mscloth render {out})")
    return 0


#: The maps builders' parameters and the ``maps`` flags (argparse attributes) that set them.
_MAPS_FLAGS = {"yarn_width": "yarn_width", "gap_fraction": "gap_fraction", "yarn_height": "yarn_height",
               "fibre_twist_deg": "twist", "ply_count": "plies", "ply_twist_deg": "ply_twist"}


def _flag(parameter: str) -> str:
    """The ``maps`` flag of a builder parameter: ``fibre_twist_deg`` -> ``--twist``."""
    return "--" + _MAPS_FLAGS.get(parameter, parameter).replace("_", "-")


def cmd_maps(args) -> int:
    from .maps.builtin import default_resolution
    from .maps.generate import generate_maps
    from .maps.generator_support import MapsWarning, format_bytes
    from .maps.preview import write_previews
    from .patterns.named import named_pattern

    params = {name: getattr(args, attr) for name, attr in _MAPS_FLAGS.items() if getattr(args, attr) is not None}
    out = Path(args.out)
    if args.ply_twist is not None and (args.plies or 1) < 2:
        raise ClothError("--ply-twist needs --plies 2 or more (a single-ply yarn has no ply twist)")
    if args.fabric:
        from .fabrics import fabric

        preset = fabric(args.pattern)
        if params:
            raise ClothError(f"{_flag(next(iter(params)))} does not apply to a fabric preset, whose yarns are "
                             "part of it")
        pattern = None
    else:
        pattern = named_pattern(args.pattern)
    if pattern is not None:
        from .maps.generate import generator_parameters

        unused = [_flag(name) for name in params if name not in generator_parameters(pattern)]
        if unused:
            raise ClothError(f"{', '.join(unused)} do{'es' if len(unused) == 1 else ''} not apply to "
                             f"{args.pattern}")
    if not args.force:
        existing = [p for p in (out / "maps.npz", out / "maps.json", out / "contact_sheet.png") if p.exists()]
        if existing:
            raise ClothError(f"{existing[0]} exists; pass --force to overwrite")
    _writable_outputs(out / "maps.json")  # (names an --out that is a file)
    resolution = args.res
    try:
        if resolution is None:
            resolution = preset.default_resolution() if args.fabric else default_resolution(pattern)
        started = time.perf_counter()
        print(f"mscloth maps: {args.pattern} at {resolution} texels along u ...", flush=True)
        # The generators' warnings name ``resolution``; here the flag is --res.
        with warnings.catch_warnings(record=True) as caught:
            maps = preset.maps(resolution) if args.fabric else generate_maps(pattern, resolution, **params)
        for warning in caught:
            message = warning.message
            text = message.naming("--res") if isinstance(message, MapsWarning) else str(message)
            warnings.warn_explicit(text, warning.category, warning.filename, warning.lineno)
        generated = time.perf_counter() - started
        maps.save(out, overwrite=args.force)
        previews = write_previews(maps, out, overwrite=args.force)
    except ResolutionError as error:
        if getattr(error, "needed", None) is not None:  # the tile would not fit in memory
            given = f"--res {args.res}" if args.res else f"the default resolution ({resolution} texels along u)"
            fix = (f"--res {error.largest} or less fits" if error.largest is not None else
                   "no --res fits; free memory or use a pattern with fewer threads")
            raise ClothError(f"{given} needs about {format_bytes(error.needed)} of memory for its maps, "
                             f"but {format_bytes(error.available)} is available: {fix}") from None
        if error.low is None:
            raise
        # In the user's terms: the flag, and the values it can take for this pattern.
        if error.low > error.high:
            raise ClothError(f"no --res fits {args.pattern}: {error.reason}") from None
        if not args.res:  # (a default that does not fit: its numbers are none the user gave)
            raise ClothError(f"the default resolution of {args.pattern} does not fit its tile; give --res in "
                             f"[{error.low}, {error.high}]") from None
        raise ClothError(f"--res must be in [{error.low}, {error.high}] for {args.pattern}, got {args.res} "
                         f"({error.reason})") from None
    except MemoryError:
        raise ClothError(f"ran out of memory making the maps of {args.pattern} at {resolution} texels along u; "
                         "give a smaller --res") from None
    h, w = maps.resolution
    print(f"generated {w}x{h} maps in {generated:.2f} s; gap fraction {1 - maps.gap.mean():.3f}")
    print(f"wrote {out / 'maps.npz'}, {out / 'maps.json'} and {len(previews)} previews "
          f"(contact sheet: {out / 'contact_sheet.png'})")
    return 0


def cmd_compare(args) -> int:
    from .evaluation.compare import run_compare
    from .scenes.builtin import SCENES

    if args.scene.lower().endswith(".xml"):
        raise ClothError(f"compare takes a built-in scene name ({', '.join(SCENES)}): an XML scene cannot be "
                         "compared yet")
    if args.scene not in SCENES:
        raise ClothError(f"unknown scene {args.scene!r}: expected one of {', '.join(SCENES)}")
    if args.variant and args.variant.startswith("scalar_"):
        # Its regions and references trace Dr.Jit arrays of shapes (mi.ShapePtr), which a
        # scalar variant does not have.
        raise ClothError(f"compare needs a JIT variant (llvm_ad_rgb or cuda_ad_rgb), got --variant {args.variant}")
    try:
        budget = float(args.budget)
    except ValueError:
        raise ClothError(f"--budget must be a positive number of seconds, got {args.budget!r}") from None
    if not (budget > 0 and budget != float("inf")):
        raise ClothError(f"--budget must be a positive number of seconds, got {args.budget!r}")
    try:
        reference_spp = int(args.reference_spp)
    except ValueError:
        raise ClothError(f"--reference-spp must be an even number >= 2, got {args.reference_spp!r}") from None
    w, h = args.res or (320, 180)
    out = Path(args.out) if args.out else Path("out") / f"compare-{args.scene}"
    json_path = Path(args.json) if args.json else None
    if json_path is not None:
        _writable_outputs(json_path)
        if json_path.exists() and not args.force:
            raise ClothError(f"{json_path} exists; pass --force to overwrite")
    if args.variant:
        setup_mitsuba(args.variant)
    run_compare(args.scene, w, h, budget=budget, reference_spp=reference_spp, out_dir=out,
                json_path=json_path, sampler=args.sampler)
    return 0


def _size(size: int) -> str:
    """A byte count in KiB below 1 MiB, in MiB above."""
    return f"{size / 2**10:.1f} KiB" if size < 2**20 else f"{size / 2**20:.1f} MiB"


def _entries(count: int, width: int = 0) -> str:
    """``1 entry``, ``3 entries`` (the count right-aligned in ``width``)."""
    return f"{count:{width}d} {'entry' if count == 1 else 'entries'}"


def cmd_fabrics(args) -> int:
    from .fabrics import FABRICS

    for f in FABRICS.values():
        count = "wales x courses" if f.structure == "knit" else "ends x picks"
        print(f"{f.name:16s} {f.pattern:12s} {f.ends_per_cm:g} x {f.picks_per_cm:g} {count}/cm, "
              f"roughness {f.roughness:g}: {f.look}")
    print("use: mscloth render swatch --fabric NAME, or <string name=\"fabric\" value=\"NAME\"/> "
          "in a cloth bsdf (UVs in metres)")
    return 0


def cmd_cache(args) -> int:
    """List the cache (per kind, or every entry with --list), or remove entries (--clear,
    optionally only those unused for --older-than days; --dry-run lists them instead)."""
    from datetime import datetime

    from .cache import cache_entries, default_cache_dir, remove_entries

    older = args.older_than
    if older is not None:
        try:
            older = float(older)
        except ValueError:
            older = float("nan")
        if not (older >= 0.0 and older != float("inf")):
            raise ClothError(f"--older-than must be a number of days >= 0, got {args.older_than!r}")
        if not args.clear:
            raise ClothError("--older-than only selects what --clear removes: add --clear")
    if args.dry_run and not args.clear:
        raise ClothError("--dry-run only lists what --clear would remove: add --clear")
    root = default_cache_dir()
    entries = cache_entries(root)
    if args.clear:
        if older is not None:
            cutoff = time.time() - older * 86400.0
            entries = [e for e in entries if e.last_used < cutoff]
        unused = f" unused for {older:g} days" if older is not None else ""
        if args.dry_run:
            for e in entries:
                print(f"would remove {e.kind}: {', '.join(p.name for p in e.paths)}")
            size = _size(sum(e.size for e in entries))
            print(f"mscloth cache: would remove {_entries(len(entries))} ({size}){unused} from {root}")
        else:
            freed = remove_entries(entries)
            print(f"mscloth cache: removed {_entries(len(entries))}{unused} ({_size(freed)}) from {root}")
        return 0
    print(f"mscloth cache: {root}" + ("" if root.is_dir() else " (not created yet)"))
    if args.list:
        for e in entries:
            used = datetime.fromtimestamp(e.last_used).strftime("%Y-%m-%d %H:%M")
            note = "  (an interrupted write)" if e.unfinished else ""
            print(f"  {e.kind:13s} {e.name}  {_size(e.size):>11s}  last used {used}{note}")
    kinds = {}
    for e in entries:
        count, size = kinds.get(e.kind, (0, 0))
        kinds[e.kind] = (count + 1, size + e.size)
    for kind, (count, size) in kinds.items():
        print(f"  {kind:13s} {_entries(count, 5):13s}  {_size(size):>11s}")
    print(f"  {'total':13s} {_entries(len(entries), 5):13s}  {_size(sum(e.size for e in entries)):>11s}")
    return 0


#: --variant's help: mscloth's BSDF is RGB (mscloth.setup_mitsuba refuses other variants).
VARIANT_HELP = ("an RGB Mitsuba variant: scalar_rgb, llvm_ad_rgb or cuda_ad_rgb (mono, spectral and "
                "polarized ones are refused; default: mscloth.default_variant())")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="mscloth", description="Multi-scale cloth appearance for Mitsuba 3.")
    parser.add_argument("--version", action="version", version=f"mscloth {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    demo = sub.add_parser("demo", help="render the demo scene (silk charmeuse and denim drapes)")
    demo.add_argument("--out", default="out", help="output directory (default: out); its demo.exr and demo.png "
                                                   "are replaced on each run")
    demo.add_argument("--spp", type=_positive_int(1, 65536), default=64, help="samples per pixel (default 64)")
    demo.add_argument("--res", type=_positive_int(16, 8192), default=512, help="image width and height (default 512)")
    demo.add_argument("--variant", default=None, help=VARIANT_HELP)
    demo.set_defaults(func=cmd_demo)

    render = sub.add_parser("render", help=f"render a built-in scene ({', '.join(SCENE_NAMES)}) or a Mitsuba XML file")
    render.add_argument("scene", help=f"{', '.join(SCENE_NAMES)}, or a .xml file")
    render.add_argument("--fabric", default=None, help="swatch: the fabric preset (default silk-charmeuse; "
                                                       "see mscloth fabrics)")
    render.add_argument("--view", default=None, choices=("close", "arm", "room"),
                        help="swatch: close-up (yarns, parallax), arm's length, or across a room (default arm)")
    render.add_argument("--light", default=None, choices=("studio", "sunsky"),
                        help="swatch: key, fill and rim area lights, or Mitsuba's sunsky (default studio)")
    render.add_argument("--spp", type=_positive_int(1, 65536), default=64, help="samples per pixel (default 64)")
    render.add_argument("--res", type=_resolution_arg, default=None, help="WIDTHxHEIGHT (default: the scene's)")
    render.add_argument("--variant", default=None, help=VARIANT_HELP)
    render.add_argument("--out", default=None, help="output EXR (default out/SCENE.exr: the built-in scene's "
                                                     "name or the XML file's stem); a PNG is written beside it")
    render.add_argument("--force", action="store_true", help="overwrite an existing EXR or PNG")
    render.add_argument("--sampler", default=None, choices=PIXEL_SAMPLERS,
                        help=f"built-in scenes: the pixel sampler (default {DEFAULT_PIXEL_SAMPLER})")
    render.set_defaults(func=cmd_render)

    scene = sub.add_parser("scene", help="write a built-in scene as Mitsuba XML to start from")
    scene.add_argument("name", help=", ".join(SCENE_NAMES))
    scene.add_argument("--out", required=True, help="output .xml file")
    scene.add_argument("--res", type=_resolution_arg, default=None,
                       help="WIDTHxHEIGHT (default: the scene's, as mscloth render's)")
    scene.add_argument("--force", action="store_true", help="overwrite an existing file")
    scene.add_argument("--variant", default=None, help=VARIANT_HELP)
    scene.add_argument("--fabric", default=None, help="swatch: the fabric preset (default silk-charmeuse)")
    scene.add_argument("--view", default=None, choices=("close", "arm", "room"), help="swatch: the view (default arm)")
    scene.add_argument("--light", default=None, choices=("studio", "sunsky"), help="swatch: the lighting (default studio)")
    scene.set_defaults(func=cmd_scene)

    maps = sub.add_parser("maps", help="generate the fibre-level maps of a pattern (weave, WIF draft, knit)")
    maps.add_argument("pattern", help="pattern name (plain, twill-2-1-S, satin-8-3, basket-2, jersey, rib-2-2, garter, seed) or a .wif file")
    maps.add_argument("--res", type=_maps_res, default=None,
                      help="texels along u (default: 32 per thread, in [128, 320]; knits 64 per wale, in [64, 320]; at least 8 per thread or wale up to 1024; always one the tile takes)")
    maps.add_argument("--out", required=True, help="output directory")
    maps.add_argument("--force", action="store_true", help="overwrite maps already in --out")
    maps.add_argument("--yarn-width", type=float, default=None, help="yarn width / thread spacing, (0, 1]")
    maps.add_argument("--gap-fraction", type=float, default=None, help="fraction of the tile that is holes, [0, 1)")
    maps.add_argument("--yarn-height", type=float, default=None, help="crimp: centreline undulation / yarn width")
    maps.add_argument("--twist", type=float, default=None, help="fibre twist angle in degrees (S > 0, Z < 0)")
    maps.add_argument("--plies", type=int, default=None, help="plies per yarn (1-8)")
    maps.add_argument("--ply-twist", type=float, default=None,
                      help="ply twist angle in degrees, (0, 90); with --plies 2 or more")
    maps.add_argument("--fabric", action="store_true",
                      help="PATTERN names a fabric preset (mscloth fabrics): its maps at its true thread count")
    maps.set_defaults(func=cmd_maps)

    compare = sub.add_parser("compare", help="multi-scale vs brute-force cloth: equal-error speed-up near, middle, far")
    compare.add_argument("scene", help=", ".join(SCENE_NAMES))
    compare.add_argument("--budget", default="60", help="render seconds for both convergence curves together (default 60)")
    compare.add_argument("--res", type=_resolution_arg, default=None, help="WIDTHxHEIGHT (default 320x180)")
    compare.add_argument("--json", default=None, help="write the figures as JSON to this file")
    compare.add_argument("--force", action="store_true", help="overwrite an existing --json file")
    compare.add_argument("--out", default=None, help="report directory (default out/compare-SCENE); "
                                                     "its report is replaced on each run")
    compare.add_argument("--reference-spp", default="1024", help="spp of the brute-force reference (default 1024)")
    compare.add_argument("--variant", default=None,
                         help="a JIT RGB Mitsuba variant, llvm_ad_rgb or cuda_ad_rgb (default: "
                              "mscloth.default_variant())")
    compare.add_argument("--sampler", default=None, choices=PIXEL_SAMPLERS,
                         help=f"the pixel sampler of both methods (default {DEFAULT_PIXEL_SAMPLER})")
    compare.set_defaults(func=cmd_compare)

    cache = sub.add_parser("cache", help="what the cache ($MSCLOTH_CACHE or ~/.cache/mscloth) holds; --clear empties it")
    cache.add_argument("--list", action="store_true", help="one line per entry (kind, name, size, last use)")
    cache.add_argument("--clear", action="store_true", help="remove mscloth's entries (other files are left alone)")
    cache.add_argument("--older-than", default=None, metavar="DAYS",
                       help="with --clear: only entries unused for DAYS days (a load marks an entry used)")
    cache.add_argument("--dry-run", action="store_true", help="with --clear: list what would be removed")
    cache.set_defaults(func=cmd_cache)

    fabrics = sub.add_parser("fabrics", help="list the fabric presets (cloth's fabric parameter)")
    fabrics.set_defaults(func=cmd_fabrics)
    return parser


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning as one line, like errors (not the source line that raised it)."""
    text = str(message).removeprefix("mscloth: ")
    print(f"mscloth: warning: {text}", file=file or sys.stderr)


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    with warnings.catch_warnings():
        warnings.showwarning = _show_warning
        try:
            code = args.func(args)
            sys.stdout.flush()  # here, not at exit: a reader that stopped early is handled below
            return code
        except BrokenPipeError:
            # The reader closed the pipe (`mscloth cache --list | head`): stop quietly, as ls
            # does. Python's recipe: point stdout at devnull so its flush at exit does not fail
            # again. 141 (128 + SIGPIPE) is what ls's death by SIGPIPE gives the shell.
            try:
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            except (OSError, ValueError):  # a stdout without a file descriptor (captured)
                pass
            return 141
        except ClothError as error:
            print(f"mscloth: error: {error}", file=sys.stderr)
            return 2
        except OSError as error:
            print(f"mscloth: error: {error}", file=sys.stderr)
            return 2
        except (KeyboardInterrupt, RuntimeError) as error:
            from .render import interrupted

            if not interrupted(error):
                raise
            print("\nmscloth: interrupted; nothing written", file=sys.stderr)
            return 130
