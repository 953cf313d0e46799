"""Named weaves, pattern names, generate_maps and `mscloth maps`."""
import json
import subprocess
import sys

import numpy as np
import pytest

from mscloth.errors import ParameterError, PatternError
from mscloth.maps.generate import generate_maps
from mscloth.maps.woven import srgb_to_linear, woven_maps
from mscloth.patterns import Draft, basket, named_pattern, plain, satin, twill

T, F = True, False


def test_plain():
    assert np.array_equal(plain(), [[T, F], [F, T]])


def test_twill_2_2_z_and_s():
    z = twill(2, 2, "Z")
    assert np.array_equal(z, [[T, F, F, T], [T, T, F, F], [F, T, T, F], [F, F, T, T]])
    # S twill is the mirror image: the diagonal runs the other way.
    assert np.array_equal(twill(2, 2, "S"), z[:, ::-1][:, np.r_[3, 0:3]])
    # every end floats over exactly `over` picks, every pick is crossed by `over` ends
    t31 = twill(3, 1)
    assert np.all(t31.sum(axis=0) == 3) and np.all(t31.sum(axis=1) == 3)


def test_satin_5_2_interlaces_once_per_end_and_pick():
    s = satin(5, 2)
    expected = np.ones((5, 5), bool)
    for j in range(5):
        expected[(2 * j) % 5, j] = False
    assert np.array_equal(s, expected)
    assert np.all((~s).sum(axis=0) == 1) and np.all((~s).sum(axis=1) == 1)
    with pytest.raises(PatternError, match="coprime"):
        satin(6, 2)
    with pytest.raises(PatternError, match=r"\[2, 3\]"):
        satin(5, 1)


def test_basket_2():
    assert np.array_equal(basket(2), [[T, T, F, F], [T, T, F, F], [F, F, T, T], [F, F, T, T]])


@pytest.mark.parametrize("name,shape", [("plain", (2, 2)), ("twill-2-1", (3, 3)), ("twill-3-1-S", (4, 4)),
                                        ("satin-8-3", (8, 8)), ("sateen-5-2", (5, 5)), ("basket-3", (6, 6))])
def test_pattern_names(name, shape):
    draft = named_pattern(name)
    assert isinstance(draft, Draft) and draft.drawdown.shape == shape


def test_sateen_is_satin_inverted():
    assert np.array_equal(named_pattern("sateen-5-2").drawdown, ~named_pattern("satin-5-2").drawdown)


@pytest.mark.parametrize("bad", ["twill-x", "satin-1-2-3", "nonsense", "basket-0"])
def test_bad_pattern_names(bad):
    with pytest.raises(PatternError):
        named_pattern(bad)


@pytest.mark.parametrize("gap", [0.0, 0.04, 0.1, 0.25])
def test_gap_fraction_parameter(gap):
    maps = generate_maps("twill-2-2", 256, gap_fraction=gap)
    # Texel-centre sampling: the hole fraction is exact up to one texel row/column per thread.
    texels_per_thread = 256 / 4
    assert abs((1.0 - maps.gap.mean()) - gap) <= 2.0 / texels_per_thread


def test_draft_colours_become_linear_albedo():
    draft = Draft(plain(), warp_colors=[(1.0, 0.5, 0.0)] * 2, weft_colors=[(0.0, 0.0, 1.0)] * 2)
    maps = woven_maps(draft, 64)
    warp = maps.albedo[maps.yarn_id == 0][0]
    np.testing.assert_allclose(warp, srgb_to_linear([1.0, 0.5, 0.0]), rtol=1e-6)
    assert abs(warp[1] - 0.214) < 1e-3  # sRGB 0.5 is linear 0.214
    np.testing.assert_allclose(maps.albedo[maps.yarn_id == 2][0], [0, 0, 1])


def test_per_thread_spacing_sets_tile_aspect_and_bands():
    # Warp ends twice as far apart as weft picks: the tile is twice as wide as high.
    draft = Draft(plain(), warp_spacing=[1.0, 1.0], weft_spacing=[0.5, 0.5],
                  warp_thickness=0.8, weft_thickness=0.4)
    maps = woven_maps(draft, 128)
    assert maps.resolution == (64, 128)
    assert maps.meta["tile_size_mm"] == [2.0, 1.0]
    # An uneven warp: end 0 is 3x wider than end 1, and so is its column band.
    draft = Draft(basket(1), warp_spacing=[1.5, 0.5], weft_spacing=[1.0, 1.0],
                  warp_thickness=[1.2, 0.4], weft_thickness=0.8)
    maps = woven_maps(draft, (64, 64))
    cols0 = np.count_nonzero(np.any(maps.yarn_id == 0, axis=0))
    cols1 = np.count_nonzero(np.any(maps.yarn_id == 1, axis=0))
    assert abs(cols0 / cols1 - 3.0) < 0.25


def test_plied_yarn_is_seamless_and_unit():
    small = woven_maps(plain(), (64, 64), ply_count=3, ply_twist_deg=35.0)
    big = woven_maps(np.tile(plain(), (2, 2)), (128, 128), ply_count=3, ply_twist_deg=35.0)
    np.testing.assert_allclose(np.linalg.norm(small.tangent, axis=-1), 1.0, atol=1e-5)
    np.testing.assert_allclose(big.tangent, np.tile(small.tangent, (2, 2, 1)), atol=1e-5)
    # Plies change the fibre directions: not the same map as a single yarn.
    single = woven_maps(plain(), (64, 64))
    assert np.mean(np.abs(single.tangent - small.tangent)) > 0.05


def test_ply_parameters_validated():
    with pytest.raises(ParameterError, match="ply_count"):
        woven_maps(plain(), 64, ply_count=0)
    with pytest.raises(ParameterError, match="ply_twist_deg"):
        woven_maps(plain(), 64, ply_count=2, ply_twist_deg=0.0)
    with pytest.raises(ParameterError, match="yarn_width or gap_fraction"):
        woven_maps(plain(), 64, yarn_width=0.5, gap_fraction=0.1)


def test_generate_maps_refuses_parameters_it_does_not_take():
    with pytest.raises(ParameterError, match="does not take colour_depth"):
        generate_maps("plain", 64, colour_depth=3)


def test_cli_maps_writes_everything_and_never_overwrites(tmp_path):
    out = tmp_path / "twill"
    cmd = [sys.executable, "-m", "mscloth", "maps", "twill-2-1", "--res", "96", "--out", str(out), "--plies", "2"]
    first = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert first.returncode == 0, first.stderr
    for name in ("maps.npz", "maps.json", "contact_sheet.png", "tangent.png", "gap.png", "albedo.png"):
        assert (out / name).stat().st_size > 0, name
    meta = json.loads((out / "maps.json").read_text())["meta"]
    assert meta["ply_count"] == 2 and meta["generator"] == "woven"
    before = (out / "maps.npz").read_bytes()
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert again.returncode != 0 and "--force" in again.stderr
    assert (out / "maps.npz").read_bytes() == before


def test_bsdf_takes_pattern_names_and_keeps_the_tile_aspect():
    import mitsuba as mi

    import mscloth
    from mscloth.loading import load_dict

    mscloth.register()
    bsdf = load_dict({"type": "cloth", "pattern": "twill-2-1-S", "uv_scale": 4.0})
    # The default tile: 32 texels per thread for 3 threads, raised to the 128 minimum.
    assert "128x128" in str(bsdf)
    params = mi.traverse(bsdf)
    assert abs(float(params["uv_scale_v"][0]) - 4.0) < 1e-6


def test_bsdf_takes_wif_files_and_knits(tmp_path):
    from pathlib import Path

    import mscloth
    from mscloth.loading import load_dict

    mscloth.register()
    wif = Path(__file__).resolve().parents[2] / "shared" / "data" / "wif" / "2229.wif"
    # 24 threads at 32 texels each capped at 320 (13 per thread, above the minimum 8).
    assert "320x320" in str(load_dict({"type": "cloth", "pattern": str(wif)}))
    jersey = load_dict({"type": "cloth", "pattern": "jersey", "resolution": 64})
    assert "64x" in str(jersey)
    with pytest.raises(PatternError, match="does not exist"):
        load_dict({"type": "cloth", "pattern": str(tmp_path / "missing.wif")})


@pytest.mark.parametrize("pattern", ["jersey", "rib-2-2", "WIF"])
def test_cli_maps_takes_knits_and_wif_files(tmp_path, pattern):
    from pathlib import Path

    if pattern == "WIF":
        pattern = str(Path(__file__).resolve().parents[2] / "shared" / "data" / "wif" / "8452.wif")
    out = tmp_path / "maps"
    result = subprocess.run([sys.executable, "-m", "mscloth", "maps", pattern, "--res", "256", "--out", str(out)],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    meta = json.loads((out / "maps.json").read_text())["meta"]
    assert meta["generator"] in ("woven", "knit")
    assert (out / "contact_sheet.png").stat().st_size > 0


@pytest.mark.parametrize("pattern,stitches", [("garter", [[1], [0]]), ("seed", [[1, 0], [0, 1]])])
def test_cli_maps_takes_garter_and_seed(tmp_path, pattern, stitches):
    # The README lists them among the knits `mscloth maps` and `pattern` take.
    from mscloth.cli import main

    out = tmp_path / pattern
    assert main(["maps", pattern, "--res", "32", "--out", str(out)]) == 0
    meta = json.loads((out / "maps.json").read_text())["meta"]
    assert meta["generator"] == "knit" and meta["stitches"] == stitches
    assert named_pattern(pattern).name == pattern


def test_drawdown_array_directly():
    maps = generate_maps(np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1]]), 96)
    assert maps.resolution == (96, 96)
    assert maps.meta["drawdown"] == [[1, 0, 0], [0, 1, 0], [0, 0, 1]]


def test_cli_maps_says_which_res_the_pattern_takes(tmp_path, capsys):
    """8452.wif is 84 ends by 100 picks, 1.19 times as tall as wide: at 2 texels per thread
    and at most 8192 per side --res (the width) must be in [168, 6881], whichever side runs
    out first."""
    from pathlib import Path

    from mscloth.cli import main

    wif = str(Path(__file__).resolve().parents[2] / "shared" / "data" / "wif" / "8452.wif")
    for res, why in (("128", "its height would be 152 texels"), ("6882", "at most 8192 texels")):
        assert main(["maps", wif, "--res", res, "--out", str(tmp_path / "m")]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"mscloth: error: --res must be in [168, 6881] for {wif}, got {res} (")
        assert why in err and err.count("\n") == 1
    # The range is exact: its low end generates, one past either end does not.
    pattern = named_pattern(wif)
    assert generate_maps(pattern, 168).resolution == (200, 168)
    for res in (167, 6882):
        with pytest.raises(ParameterError, match=r"resolution \(texels along u\) must be in \[168, 6881\]"):
            generate_maps(pattern, res)
    assert not (tmp_path / "m").exists()


# ------------------------------------------------------------ --res: fits, limits, memory
def _write_wif(path, ends: int, picks: int, warp_spacing_cm: float = 0.05, weft_spacing_cm: float = 0.05):
    """A 4-shaft twill WIF of ``ends`` x ``picks``, in centimetres."""
    lines = ["[WIF]", "Version=1.1", "Date=2024", "Developers=test", "Source Program=test", "[CONTENTS]",
             "WEAVING=yes", "WARP=yes", "WEFT=yes", "THREADING=yes", "TIEUP=yes", "TREADLING=yes",
             "[WEAVING]", "Shafts=4", "Treadles=4", "Rising Shed=yes",
             "[WARP]", f"Threads={ends}", "Units=Centimeters", f"Spacing={warp_spacing_cm}", "Thickness=0.04",
             "[WEFT]", f"Threads={picks}", "Units=Centimeters", f"Spacing={weft_spacing_cm}", "Thickness=0.04",
             "[THREADING]", *(f"{k}={(k - 1) % 4 + 1}" for k in range(1, ends + 1)),
             "[TIEUP]", "1=1,2", "2=2,3", "3=3,4", "4=4,1",
             "[TREADLING]", *(f"{k}={(k - 1) % 4 + 1}" for k in range(1, picks + 1))]
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def test_default_res_fits_a_tall_draft_in_the_cli_and_the_bsdf(tmp_path, capsys):
    """4 ends x 1000 picks: a tile 250 times as tall as wide takes 8 to 32 texels along u;
    the default was 128 (32000 tall), refused although the user gave no resolution."""
    from mscloth.cli import main
    from mscloth.maps.builtin import resolve_pattern

    wif = _write_wif(tmp_path / "tall.wif", 4, 1000)
    assert main(["maps", wif, "--out", str(tmp_path / "m")]) == 0
    assert "generated 32x8000 maps" in capsys.readouterr().out
    assert resolve_pattern(wif).resolution == (8000, 32)


def test_no_res_fits_a_draft_says_so_in_one_line(tmp_path, capsys):
    """4 ends x 50 picks, the picks 100 times as far apart as the ends: any width that holds
    the ends (8 texels) is 10000 texels tall. No --res can help, given or not: say what can."""
    from mscloth.cli import main

    wif = _write_wif(tmp_path / "far.wif", 4, 50, warp_spacing_cm=0.01, weft_spacing_cm=1.0)
    for extra in ([], ["--res", "64"]):
        assert main(["maps", wif, *extra, "--out", str(tmp_path / "m")]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"mscloth: error: no --res fits {wif}: at its aspect H/W = 1250, a tile as wide "
                              "as its 4 warp ends need (8 texels) would be 10000 texels tall, more than the "
                              "8192 a tile side may have; fewer weft picks per repeat, or weft picks spaced "
                              "more closely, would fit\n")
        assert err.count("\n") == 1 and "got" not in err and "default" not in err
    assert not (tmp_path / "m").exists()


def test_cli_maps_res_stops_at_the_bsdfs_8192(tmp_path, capsys, monkeypatch):
    from mscloth.cli import main
    from mscloth.maps import generate

    def refuse(*args, **kwargs):
        raise AssertionError("--res 8193 was taken")  # (and would need ~40 GiB)
    monkeypatch.setattr(generate, "generate_maps", refuse)
    with pytest.raises(SystemExit):
        main(["maps", "plain", "--res", "8193", "--out", str(tmp_path / "m")])
    assert "expected an integer in [8, 8192], got 8193" in capsys.readouterr().err


def test_cli_maps_refuses_what_would_not_fit_in_memory(tmp_path, capsys, monkeypatch):
    from mscloth.cli import main
    from mscloth.maps import generator_support

    monkeypatch.setattr(generator_support, "available_memory", lambda: 200 << 20)
    assert main(["maps", "plain", "--res", "1024", "--out", str(tmp_path / "m")]) == 2
    err = capsys.readouterr().err
    assert err == ("mscloth: error: --res 1024 needs about 704 MiB of memory for its maps, but 200 MiB is "
                   "available: --res 472 or less fits\n")
    assert not (tmp_path / "m").exists()


def test_cli_maps_turns_memory_error_into_one_line(tmp_path, capsys, monkeypatch):
    from mscloth.cli import main
    from mscloth.maps import generate

    def exhausted(*args, **kwargs):
        raise MemoryError
    monkeypatch.setattr(generate, "generate_maps", exhausted)
    assert main(["maps", "plain", "--res", "64", "--out", str(tmp_path / "m")]) == 2
    assert capsys.readouterr().err == ("mscloth: error: ran out of memory making the maps of plain at 64 texels "
                                       "along u; give a smaller --res\n")


@pytest.mark.parametrize("flag, value, suggested", [("--gap-fraction", "0.99", 798), ("--yarn-width", "0.01", 400)])
def test_cli_maps_warns_of_an_invisible_yarn_naming_res(tmp_path, capsys, flag, value, suggested):
    from mscloth.cli import main

    assert main(["maps", "plain", "--res", "128", flag, value, "--out", str(tmp_path / "m")]) == 0
    captured = capsys.readouterr()
    assert "gap fraction 1.000" in captured.out
    warning = [line for line in captured.err.splitlines() if line.startswith("mscloth: warning: ")]
    assert len(warning) == 1 and warning[0].endswith(f"--res {suggested} or more resolves it"), captured.err
