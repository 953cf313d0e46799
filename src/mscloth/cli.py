"""The ``mscloth`` command line."""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from . import __version__
from .errors import ClothError


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


def _setup(variant: str | None) -> str:
    import mitsuba as mi

    from . import default_variant, register

    chosen = variant or default_variant()
    if chosen not in mi.variants():
        raise ClothError(f"unknown variant {chosen!r}: expected one of {', '.join(mi.variants())}")
    mi.set_variant(chosen)
    register()
    return chosen


def cmd_demo(args) -> int:
    import mitsuba as mi

    from .loading import load_dict
    from .render import render_progressive, write_images
    from .scenes.demo import demo_scene

    variant = _setup(args.variant)
    out = Path(args.out)
    exr = out / "demo.exr"
    print(f"mscloth demo: {args.res}x{args.res}, {args.spp} spp, variant {variant}")
    started = time.perf_counter()
    scene = load_dict(demo_scene(resolution=args.res))
    image = render_progressive(scene, args.spp, label="demo")
    seconds = time.perf_counter() - started
    exr, png = write_images(image, exr)
    rate = args.res * args.res * args.spp / seconds
    print(f"wrote {exr} and {png} in {seconds:.1f} s ({rate / 1e6:.2f} M samples/s)")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="mscloth", description="Multi-scale cloth appearance for Mitsuba 3.")
    parser.add_argument("--version", action="version", version=f"mscloth {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    demo = sub.add_parser("demo", help="render the default scene (cloth sphere and plane)")
    demo.add_argument("--out", default="out", help="output directory (default: out)")
    demo.add_argument("--spp", type=_positive_int(1, 65536), default=64, help="samples per pixel (default 64)")
    demo.add_argument("--res", type=_positive_int(16, 8192), default=512, help="image width and height (default 512)")
    demo.add_argument("--variant", default=None, help="Mitsuba variant (default: mscloth.default_variant())")
    demo.set_defaults(func=cmd_demo)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except ClothError as error:
        print(f"mscloth: error: {error}", file=sys.stderr)
        return 2
    except OSError as error:
        print(f"mscloth: error: {error}", file=sys.stderr)
        return 2
