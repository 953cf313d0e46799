"""Rendering with progress, and writing images without leaving half-written files."""
from __future__ import annotations

import gc
import signal
import sys
import threading
import time
from pathlib import Path

import drjit as dr
import mitsuba as mi

from .atomic import atomic_path


def progress_bar(done: int, total: int, started: float, label: str, stream=None) -> None:
    """One-line progress bar, redrawn in place (on ``stream``, default: sys.stderr as it is
    now, not as it was at import: the CLI also runs in-process, under redirected streams)."""
    stream = sys.stderr if stream is None else stream
    width = 30
    filled = int(width * done / max(total, 1))
    elapsed = time.perf_counter() - started
    eta = elapsed / done * (total - done) if done else 0.0
    stream.write(f"\r{label} [{'#' * filled}{'.' * (width - filled)}] {done}/{total} "
                 f"{elapsed:5.1f}s elapsed, {eta:5.1f}s left")
    if done == total:
        stream.write("\n")
    stream.flush()


class KernelCompilation:
    """``with KernelCompilation() as compiling:`` -- ``compiling.seconds``: the time Dr.Jit
    spent compiling kernels (code generation + backend, from its kernel history) in the block.

    Each new kernel costs seconds to compile (the multi-scale cloth's, several), once per
    process and kernel; it does not grow with the samples, so rates leave it out.
    """

    def __enter__(self) -> "KernelCompilation":
        dr.sync_thread()
        self.seconds = 0.0
        self._had_history = dr.flag(dr.JitFlag.KernelHistory)
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        dr.kernel_history()  # clear
        return self

    def __exit__(self, *exc) -> None:
        try:
            dr.sync_thread()
            history = dr.kernel_history()
        finally:
            dr.set_flag(dr.JitFlag.KernelHistory, self._had_history)
        self.seconds = sum(k.get("codegen_time", 0.0) + k.get("backend_time", 0.0) for k in history) / 1000.0


def throughput_text(samples: int, seconds: float, compile_seconds: float) -> str:
    """``"2.00 M samples/s (render 1.50 s, plus 3.0 s kernel compilation)"``: ``samples`` over
    the ``seconds`` taken less the kernel compilation among them (:class:`KernelCompilation`)."""
    compile_seconds = min(max(compile_seconds, 0.0), seconds)
    render = seconds - compile_seconds
    rate = f"{samples / render / 1e6:.2f} M samples/s" if render > 0 else "rate not measurable"
    return f"{rate} (render {render:.2f} s, plus {compile_seconds:.1f} s kernel compilation)"


#: Camera samples per progressive pass, about: each pass traces the render kernel again in
#: Python (~0.1 s with cloth on 2 cores), so a small render is one pass, not eight.
SAMPLES_PER_PASS = 4_000_000
MAX_PASSES = 8


def pass_count(pixels: int, spp: int, passes: int | None = None) -> int:
    """Passes for ``spp`` samples per pixel over ``pixels`` pixels: ``passes`` if given,
    else one per ~SAMPLES_PER_PASS samples, at most MAX_PASSES; lowered until it divides
    ``spp``."""
    if passes is None:
        passes = round(pixels * spp / SAMPLES_PER_PASS)
    passes = max(1, min(passes, spp, MAX_PASSES))
    while spp % passes:
        passes -= 1
    return passes


def samples_taken(scene, spp: int) -> int:
    """The samples per pixel ``scene``'s sampler takes when asked for ``spp`` (a
    ``multijitter`` or ``stratified`` sampler rounds up: 10 -> 12), asked quietly."""
    from .integrators.sky_share_pilot import render_sample_count

    return render_sample_count(scene.sensors()[0], spp)


def interrupted(error: BaseException) -> bool:
    """Whether ``error`` is Ctrl-C: a KeyboardInterrupt, or an error raised because of one
    (Dr.Jit wraps one raised in a Python integrator's render in a RuntimeError)."""
    seen = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, KeyboardInterrupt):
            return True
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return False


class _InterruptWatch(mi.Appender):
    """Notices Ctrl-C during a render. Mitsuba takes SIGINT while it renders and cancels the
    pass; around a Python integrator (its render nested in Mitsuba's) it also swallows the
    signal, so Python never raises KeyboardInterrupt. Its warning still passes the log."""

    def __init__(self):
        super().__init__()
        self.interrupted = False

    def append(self, level, text):
        if "Received interrupt signal" in text:
            self.interrupted = True

    def log_progress(self, *args):
        pass


def render_progressive(scene, spp: int, passes: int | None = None, seed: int = 0,
                       label: str = "render", quiet: bool = False):
    """Render ``spp`` samples per pixel in passes (showing progress; :func:`pass_count`,
    fewer where a pass's count would not be one the scene's sampler takes); return the mean
    image. Ctrl-C stops it after the pass it interrupts: KeyboardInterrupt.

    Each pass is an independent render with its own seed, so the average equals
    one render at the full sample count in expectation.
    """
    if spp < 1:
        raise ValueError(f"spp must be >= 1, got {spp}")
    size = scene.sensors()[0].film().crop_size()
    passes = pass_count(int(size[0]) * int(size[1]), spp, passes)
    # (A sampler that rounds a pass's count up would render more than spp in all.)
    while passes > 1 and (spp % passes or samples_taken(scene, spp // passes) != spp // passes):
        passes -= 1
    per_pass = spp // passes
    # Free unreachable plugin instances first: Dr.Jit traces a virtual call through every
    # registered BSDF, and one freed by the garbage collector mid-trace crashes it.
    gc.collect()
    main_thread = threading.current_thread() is threading.main_thread()
    handler = signal.getsignal(signal.SIGINT) if main_thread else None
    watch = _InterruptWatch()
    logger = mi.logger()
    logger.add_appender(watch)
    started = time.perf_counter()
    total = None
    try:
        for i in range(passes):
            try:
                img = mi.render(scene, spp=per_pass, seed=seed + i)
            except RuntimeError as error:
                if interrupted(error):
                    raise KeyboardInterrupt from None
                raise
            if handler is not None:  # (Mitsuba's handler may stay installed after it)
                signal.signal(signal.SIGINT, handler)
            if watch.interrupted:
                raise KeyboardInterrupt
            total = img if total is None else total + img
            dr.eval(total)
            if not quiet:
                progress_bar(i + 1, passes, started, label)
    finally:
        logger.remove_appender(watch)
    return total / passes


def write_images(image, exr_path: Path) -> tuple[Path, Path]:
    """Write ``image`` as linear EXR and sRGB PNG beside it (same stem); atomically."""
    exr_path = Path(exr_path)
    png_path = exr_path.with_suffix(".png")
    # The colour channels only: clothpath appends its footprint AOVs after RGB.
    rgb = mi.TensorXf(image)[..., :3] if image.shape[-1] > 3 else image
    bitmap = mi.Bitmap(rgb)
    with atomic_path(exr_path) as tmp:
        bitmap.write(tmp)
    png = bitmap.convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.UInt8, srgb_gamma=True)
    with atomic_path(png_path) as tmp:
        png.write(tmp)
    return exr_path, png_path
