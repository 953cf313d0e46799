"""Package set-up: variant choice, registration, the demo scene, the command line."""
import os
import subprocess
import sys

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import mscloth
from mscloth import variant
from mscloth.bsdf.lobe_calibration import LobeCalibration
from mscloth.scattering import sheen


def test_default_variant_is_usable():
    chosen = mscloth.default_variant()
    assert chosen in mi.variants()
    # This machine (and CI) has Debian's libllvm19 but no GPU.
    if not dr.has_backend(dr.JitBackend.CUDA):
        assert chosen == "llvm_ad_rgb"


def test_find_libllvm_prefers_19_and_refuses_old(monkeypatch, tmp_path):
    for name in ["libLLVM-14.so.1", "libLLVM-15.so.1", "libLLVM.so.18.1", "libLLVM.so.19.1"]:
        (tmp_path / name).write_bytes(b"")
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    monkeypatch.setattr(variant, "_LLVM_GLOBS", (str(tmp_path / "libLLVM*"),))
    assert variant.find_libllvm() == str(tmp_path / "libLLVM.so.19.1")
    (tmp_path / "libLLVM.so.19.1").unlink()
    assert variant.find_libllvm() == str(tmp_path / "libLLVM.so.18.1")
    (tmp_path / "libLLVM.so.18.1").unlink()
    assert variant.find_libllvm() is None  # 14 and 15 are not usable


def test_register_is_idempotent():
    mscloth.register()
    mscloth.register()
    assert "ClothBSDF" in str(mi.load_dict({"type": "cloth"}))


@pytest.mark.parametrize("footprint", [0.0, 0.06])
def test_scalar_variant_agrees_with_llvm(footprint):
    """The plugin also runs in scalar_rgb (unit tests only: it is slow there): eval, pdf and
    sample of the fibre-level BSDF and of a footprint (0.06 UV = 8 texels of 128).

    The footprint's stratified texels and SAT rounding come from a hash of the uv, which
    Python's double-precision scalar arithmetic computes differently: both variants get the
    same fixed numbers instead. Scalar variants neither measure the lobe calibrations nor
    tabulate the sheen: the scalar BSDF gets the LLVM one's calibrations, and the LLVM one
    samples the sheen like the scalar one (the table has its own tests)."""
    wi, wo, uv = [0.3, -0.2, 0.93], [-0.4, 0.1, 0.91], [0.26, 0.13]
    ratios = []

    def values():
        mscloth.register()
        bsdf = mi.load_dict({"type": "cloth"})
        if ratios:
            assert bsdf.fibre.calibration is None
            assert isinstance(bsdf.fibre.samplers.sheen, sheen.FoldedSheenSampler)
            bsdf.fibre.calibration = LobeCalibration(ratios[0])
            bsdf.estimator.calibration = LobeCalibration(*ratios[1])
        else:
            assert isinstance(bsdf.fibre.samplers.sheen, sheen.TabulatedSheenSampler)
            ratios.append(bsdf.fibre.calibration.ratios)
            ratios.append((bsdf.estimator.calibration.albedo_ratios, bsdf.estimator.calibration.factors))
            bsdf.fibre.samplers.sheen = sheen.FoldedSheenSampler(bsdf.params.sheen_roughness)
        si = dr.zeros(mi.SurfaceInteraction3f)
        si.wi = dr.normalize(mi.Vector3f(wi))
        si.uv = mi.Point2f(uv)
        si.duv_dx = mi.Vector2f(footprint, 0.0)
        si.duv_dy = mi.Vector2f(0.0, footprint)
        ctx = mi.BSDFContext()
        out = []
        wo_v = dr.normalize(mi.Vector3f(wo))
        bsdf.estimator.shading_hash = lambda si: (mi.Point2f(0.3, 0.7), mi.Point2f(0.6, 0.2), mi.Float(0.4))
        value, pdf = bsdf.eval_pdf(ctx, si, wo_v)
        out += [np.asarray(value, dtype=float).reshape(-1)[:3], np.asarray(pdf, dtype=float).reshape(-1)[:1]]
        for s1, s2 in ((0.2, [0.3, 0.7]), (0.55, [0.8, 0.1]), (0.9, [0.45, 0.5])):
            bs, weight = bsdf.sample(ctx, si, s1, mi.Point2f(s2))
            out += [np.asarray(bs.wo, dtype=float).reshape(-1)[:3], np.asarray(bs.pdf, dtype=float).reshape(-1)[:1],
                    np.asarray(weight, dtype=float).reshape(-1)[:3]]
        return np.concatenate(out)

    llvm = values()
    try:
        mi.set_variant("scalar_rgb")
        scalar = values()
    finally:
        mi.set_variant("llvm_ad_rgb")
    assert np.all(llvm[:4] > 0)
    # Footprint values are differences of SAT corners in float32, where LLVM's fused
    # multiply-adds and scalar code round differently: a few 1e-3 relative.
    np.testing.assert_allclose(scalar, llvm, rtol=1e-4 if footprint == 0.0 else 5e-3, atol=1e-6)


def test_cli_rejects_bad_arguments(tmp_path):
    result = subprocess.run([sys.executable, "-m", "mscloth", "demo", "--spp", "0", "--out", str(tmp_path)],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode != 0
    assert "--spp" in result.stderr and "[1, 65536]" in result.stderr
    assert not any(tmp_path.iterdir())


# A cloth square seen head-on under a sky (clothpath hands the BSDF a zero direction when the
# sky is its only light: scalar floats raised ZeroDivisionError on it), and the same square
# over a floor in the sun (shadow rays from the floor cross the cloth's gaps, then miss: a
# scalar miss was asked for its BSDF, a null dereference).
_SCALAR_SCENE = """<scene version="3.0.0">
    <integrator type="clothpath"/>
    <sensor type="perspective">
        <float name="fov" value="40"/>
        <transform name="to_world"><lookat origin="0, 0, 3" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
    </sensor>
    <emitter type="constant"><rgb name="radiance" value="0.5"/></emitter>
    {sun}
    <shape type="rectangle">
        <transform name="to_world"><scale value="0.5"/><translate z="0.5"/></transform>
        <bsdf type="cloth"><integer name="resolution" value="16"/></bsdf>
    </shape>
    {floor}
</scene>
"""


@pytest.mark.parametrize("lit", ["sky", "sun"])
def test_cli_renders_with_scalar_rgb(tmp_path, lit):
    """scalar_rgb is default_variant()'s last fallback: `mscloth render` works there."""
    sun = floor = ""
    if lit == "sun":
        sun = '<emitter type="directional"><vector name="direction" value="0, 0, -1"/></emitter>'
        floor = '<shape type="rectangle"><bsdf type="diffuse"/></shape>'
    scene = tmp_path / "scene.xml"
    scene.write_text(_SCALAR_SCENE.format(sun=sun, floor=floor))
    out = tmp_path / "scalar.exr"
    result = subprocess.run([sys.executable, "-m", "mscloth", "render", str(scene), "--variant", "scalar_rgb",
                             "--spp", "2", "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    image = np.array(mi.Bitmap(str(out)))
    assert image.shape[:2] == (8, 8) and np.all(np.isfinite(image)) and image.mean() > 0.01


def _one_error_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("mscloth: error: "), err
    return lines[0]


def test_cli_refuses_a_variant_whose_backend_does_not_start(tmp_path, capsys, monkeypatch):
    from mscloth.cli import main

    if dr.has_backend(dr.JitBackend.CUDA):
        pytest.skip("this machine has a CUDA device")
    out = tmp_path / "x.exr"
    assert main(["render", "plane", "--variant", "cuda_ad_rgb", "--out", str(out)]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert "'cuda_ad_rgb'" in line and "no CUDA device" in line
    # A backend failing in a way the check does not foresee: still one line, the variant named.
    monkeypatch.setattr(variant, "variant_unavailable", lambda name: None)
    monkeypatch.setattr(mi, "set_variant", lambda name: (_ for _ in ()).throw(ImportError("jit_init failed\nmore")))
    assert main(["render", "plane", "--variant", "llvm_ad_rgb", "--out", str(out)]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert "'llvm_ad_rgb'" in line and "jit_init failed" in line
    assert not tmp_path.exists() or not any(tmp_path.iterdir())


@pytest.mark.parametrize("name", ["llvm_ad_mono", "scalar_spectral", "llvm_ad_spectral_polarized",
                                  "llvm_ad_mono_polarized"])
def test_cli_refuses_a_variant_that_is_not_rgb(tmp_path, capsys, name):
    """mscloth's BSDF is RGB: other variants are refused before they are made active (they
    failed with a Dr.Jit traceback, or a misleading energy error)."""
    from mscloth.cli import build_parser, main

    out = tmp_path / "x.exr"
    try:
        assert main(["render", "plane", "--variant", name, "--out", str(out)]) == 2
        line = _one_error_line(capsys.readouterr().err)
        assert "mscloth renders RGB variants only: scalar_rgb, llvm_ad_rgb" in line and repr(name) in line
        assert mi.variant() == "llvm_ad_rgb" and not out.exists()
        with pytest.raises(mscloth.ClothError, match="RGB variants only"):
            mscloth.setup_mitsuba(name)
    finally:  # (where it was made active, the later tests would run in it)
        mi.set_variant("llvm_ad_rgb")
    with pytest.raises(SystemExit):
        build_parser().parse_args(["render", "--help"])
    assert "an RGB Mitsuba variant" in " ".join(capsys.readouterr().out.split())


def test_cli_demo_renders_finite_cloth_and_twice_replaces_its_own_images(tmp_path, capsys):
    """`make demo`: the demo scene renders finite, lit cloth, says where it wrote and how
    long it took; run twice, its --out is its own folder, replaced without --force."""
    from mscloth.cli import main

    for _ in range(2):
        assert main(["demo", "--out", str(tmp_path), "--res", "32", "--spp", "4"]) == 0
    out = capsys.readouterr().out
    assert "wrote" in out and "demo.png" in out and " s " in out
    assert (tmp_path / "demo.exr").is_file() and (tmp_path / "demo.png").stat().st_size > 0
    image = np.array(mi.Bitmap(str(tmp_path / "demo.exr")))[..., :3]
    assert image.shape == (32, 32, 3)
    assert np.all(np.isfinite(image)) and image.mean() > 0.05


# Three cloths of different kinds (a knit by name, a woven fabric preset, a WIF draft) in one
# scene, loaded first thing in a fresh process: Mitsuba builds them on several threads at once.
_LOAD_THREE_CLOTHS = """
import sys
import mitsuba as mi
import mscloth

mi.set_variant("llvm_ad_rgb")
mscloth.register()
before = set(sys.modules)
cheap = {"resolution": 16, "multiscale": False, "visibility": False}
mi.load_dict({"type": "scene",
              "knit": {"type": "rectangle", "bsdf": {"type": "cloth", "pattern": "jersey", **cheap}},
              "fabric": {"type": "rectangle", "bsdf": {"type": "cloth", "fabric": "denim", **cheap}},
              "wif": {"type": "rectangle", "bsdf": {"type": "cloth", "pattern": sys.argv[1], **cheap}}})
print("imported while loading:", sorted(m for m in set(sys.modules) - before if m.startswith("mscloth")))
"""

_TWILL_WIF = """[WIF]
Version=1.1
Date=April 20, 1997
Developers=test
Source Program=test-suite
[WEAVING]
Shafts=4
Treadles=4
Rising Shed=true
[WARP]
Threads=4
Units=Millimeters
Spacing=0.5
[WEFT]
Threads=4
Units=Millimeters
Spacing=0.5
[THREADING]
1=1
2=2
3=3
4=4
[TIEUP]
1=1,2
2=2,3
3=3,4
4=4,1
[TREADLING]
1=1
2=2
3=3
4=4
"""


def test_cloths_of_every_kind_load_at_once_in_a_fresh_process(tmp_path):
    """Before the fix each constructor imported what it needed (patterns, maps, fabrics) on
    first use, on the parallel loader's threads: about one first load in two failed with
    ``KeyError: 'mscloth.patterns'`` or a "partially initialized module". Now
    ``register()`` imports all of it, so loading a scene imports no mscloth module."""
    wif = tmp_path / "twill.wif"
    wif.write_text(_TWILL_WIF)
    runs = [subprocess.Popen([sys.executable, "-c", _LOAD_THREE_CLOTHS, str(wif)], stdout=subprocess.PIPE,
                             stderr=subprocess.STDOUT, text=True) for _ in range(4)]
    for run in runs:
        out = run.communicate(timeout=300)[0]
        assert run.returncode == 0 and "imported while loading: []" in out, out[-3000:]


def test_loading_is_reachable_after_import_mscloth():
    """The README's ``mscloth.loading.load_file`` after ``import mscloth``: before the fix
    an AttributeError, as nothing had imported the submodule."""
    source = ("import mscloth\n"
              "print(mscloth.loading.load_file.__name__)\n"  # before any set-up, too
              "import mitsuba as mi\n"
              "mi.set_variant(mscloth.default_variant()); mscloth.register()\n"
              "print(type(mscloth.loading.load_dict({'type': 'scene'})).__name__)\n")
    result = subprocess.run([sys.executable, "-c", source], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-3000:]
    assert result.stdout.split() == ["load_file", "Scene"]
