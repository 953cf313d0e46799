"""Cloth maps: container validation, save/load, woven plain-weave geometry, previews, builtins."""
from __future__ import annotations

import json
import os
import time
import warnings

import numpy as np
import pytest
from PIL import Image

from mscloth.errors import MapsError, ParameterError, PatternError
from mscloth.maps.builtin import BUILTIN_PATTERNS, resolve_pattern
from mscloth.maps.cloth_maps import ARRAY_FIELDS, ClothMaps
from mscloth.maps.preview import write_previews
from mscloth.maps.woven import slub_factors, woven_maps
from mscloth.patterns.draft import Draft
from mscloth.patterns.weaves import plain, validate_drawdown

RES = 128


@pytest.fixture(scope="module")
def plain_maps() -> ClothMaps:
    return woven_maps(plain(), (RES, RES), yarn_width=0.8, fibre_twist_deg=30.0,
                      warp_colors=[[0.9, 0.1, 0.1], [0.1, 0.9, 0.1]],
                      weft_colors=[0.2, 0.3, 0.8])


def _arrays(maps: ClothMaps) -> dict[str, np.ndarray]:
    return {name: np.array(getattr(maps, name)) for name in ARRAY_FIELDS}


def _small(**override) -> dict:
    """Valid 2x3 map arrays; override any of them."""
    h, w = 2, 3
    arrays = dict(
        tangent=np.tile([0.0, 1.0, 0.0], (h, w, 1)),
        normal=np.tile([0.0, 0.0, 1.0], (h, w, 1)),
        height=np.zeros((h, w)),
        gap=np.ones((h, w)),
        yarn_id=np.zeros((h, w), dtype=np.int64),
        albedo=np.full((h, w, 3), 0.5),
    )
    arrays.update(override)
    return arrays


# ---------------------------------------------------------------- ClothMaps validation
def test_construct_converts_dtypes_and_is_read_only():
    maps = ClothMaps(**_small(), meta={"generator": "test", "pair": (1, 2)})
    assert maps.resolution == (2, 3)
    assert maps.tangent.dtype == np.float32 and maps.gap.dtype == np.float32
    assert maps.yarn_id.dtype == np.int32
    assert maps.meta == {"generator": "test", "pair": [1, 2]}  # JSON form
    with pytest.raises(ValueError):
        maps.height[0, 0] = 1.0


@pytest.mark.parametrize("override, words", [
    (dict(tangent=np.zeros((4, 4))), ["tangent", "(H, W, 3)", "(4, 4)"]),
    (dict(tangent=np.tile([0.0, 2.0, 0.0], (2, 3, 1))), ["tangent", "unit"]),
    (dict(normal=np.tile([0.0, 0.0, -1.0], (2, 3, 1))), ["normal", "z > 0"]),
    (dict(normal=np.zeros((3, 2, 3))), ["normal", "(2, 3, 3)"]),
    (dict(height=np.full((2, 3), np.nan)), ["height", "finite"]),
    (dict(height=np.zeros((2, 3), dtype=complex)), ["height", "dtype"]),
    (dict(gap=np.full((2, 3), 0.5)), ["gap", "{0, 1}"]),
    (dict(yarn_id=np.zeros((2, 3))), ["yarn_id", "integer"]),
    (dict(yarn_id=np.full((2, 3), -2)), ["yarn_id", "-1"]),
    (dict(yarn_id=np.full((2, 3), -1)), ["yarn_id", "gap == 0"]),
    (dict(albedo=np.full((2, 3, 3), 1.5)), ["albedo", "[0, 1]"]),
])
def test_validation_errors_name_field(override, words):
    with pytest.raises(MapsError) as info:
        ClothMaps(**_small(**override))
    for word in words:
        assert word in str(info.value)


def test_meta_must_be_json():
    with pytest.raises(MapsError, match="meta"):
        ClothMaps(**_small(), meta={"x": object()})


# ---------------------------------------------------------------- save / load
def test_round_trip_exact(plain_maps, tmp_path):
    plain_maps.save(tmp_path / "m")
    loaded = ClothMaps.load(tmp_path / "m")
    for name in ARRAY_FIELDS:
        a, b = getattr(plain_maps, name), getattr(loaded, name)
        assert a.dtype == b.dtype and np.array_equal(a, b), name
    assert loaded.meta == plain_maps.meta
    header = json.loads((tmp_path / "m" / "maps.json").read_text())
    assert header["shape"] == [RES, RES] and header["meta"]["generator"] == "woven"
    assert not [p for p in (tmp_path / "m").iterdir() if p.name.endswith(".tmp")]


def test_save_refuses_to_overwrite(plain_maps, tmp_path):
    plain_maps.save(tmp_path)
    before = (tmp_path / "maps.npz").read_bytes()
    with pytest.raises(MapsError, match="overwrite"):
        plain_maps.save(tmp_path)
    (tmp_path / "maps.npz").unlink()  # one file existing is enough to refuse
    (tmp_path / "maps.npz").write_bytes(b"user data")
    with pytest.raises(MapsError, match="overwrite"):
        plain_maps.save(tmp_path)
    assert (tmp_path / "maps.npz").read_bytes() == b"user data"
    plain_maps.save(tmp_path, overwrite=True)
    assert (tmp_path / "maps.npz").read_bytes() == before


def test_load_missing_directory(tmp_path):
    with pytest.raises(MapsError, match="does not exist"):
        ClothMaps.load(tmp_path / "nope")


def test_load_missing_npz(plain_maps, tmp_path):
    plain_maps.save(tmp_path)
    (tmp_path / "maps.npz").unlink()
    with pytest.raises(MapsError, match="maps.npz"):
        ClothMaps.load(tmp_path)


def test_load_truncated_npz(plain_maps, tmp_path):
    plain_maps.save(tmp_path)
    data = (tmp_path / "maps.npz").read_bytes()
    (tmp_path / "maps.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(MapsError, match="maps.npz") as info:
        ClothMaps.load(tmp_path)
    assert "corrupt or truncated" in str(info.value)


def test_load_npz_missing_array(plain_maps, tmp_path):
    plain_maps.save(tmp_path)
    arrays = _arrays(plain_maps)
    del arrays["albedo"]
    np.savez(tmp_path / "maps.npz", **arrays)
    with pytest.raises(MapsError, match="'albedo'"):
        ClothMaps.load(tmp_path)


def test_load_bad_json(plain_maps, tmp_path):
    plain_maps.save(tmp_path)
    (tmp_path / "maps.json").write_text("{not json")
    with pytest.raises(MapsError, match="maps.json"):
        ClothMaps.load(tmp_path)


def test_load_invalid_array_content(plain_maps, tmp_path):
    plain_maps.save(tmp_path)
    arrays = _arrays(plain_maps)
    arrays["tangent"] = arrays["tangent"] * 2
    np.savez(tmp_path / "maps.npz", **arrays)
    with pytest.raises(MapsError, match="tangent"):
        ClothMaps.load(tmp_path)


# ---------------------------------------------------------------- drawdowns
def test_plain_drawdown():
    assert np.array_equal(plain(), [[True, False], [False, True]])
    assert plain().dtype == bool


@pytest.mark.parametrize("bad", [[1, 0, 1], [[]], [[1, 2], [0, 1]], [["a", "b"]],
                                 np.zeros((2, 2, 2), bool)])
def test_validate_drawdown_rejects(bad):
    with pytest.raises(PatternError, match="drawdown"):
        validate_drawdown(bad)


def test_validate_drawdown_accepts_01():
    assert np.array_equal(validate_drawdown([[1, 0], [0, 1]]), plain())


# ---------------------------------------------------------------- woven geometry
def test_unit_vectors(plain_maps):
    for name in ("tangent", "normal"):
        length = np.linalg.norm(getattr(plain_maps, name), axis=-1)
        assert np.allclose(length, 1.0, atol=1e-5), name
    assert np.all(plain_maps.normal[..., 2] > 0)


def _wrap_step_ok(a: np.ndarray, axis: int) -> None:
    """The step across the tile seam is no larger than the largest interior step."""
    interior = np.abs(np.diff(a, axis=axis))
    seam = np.abs(np.take(a, 0, axis=axis) - np.take(a, -1, axis=axis))
    assert seam.max() <= interior.max() + 1e-6


def test_seamless(plain_maps):
    for axis in (0, 1):
        _wrap_step_ok(plain_maps.height, axis)
        _wrap_step_ok(plain_maps.tangent, axis)
        _wrap_step_ok(plain_maps.normal, axis)
    # Stronger: the tile is exactly one period. The maps of a 2x2 repeat of the drawdown at
    # twice the resolution must equal the tile laid 2x2, seams included (heights halve: they
    # are in tile widths and the big tile is two repeats wide).
    big = woven_maps(np.tile(plain(), (2, 2)), (2 * RES, 2 * RES), yarn_width=0.8,
                     fibre_twist_deg=30.0)
    small = woven_maps(plain(), (RES, RES), yarn_width=0.8, fibre_twist_deg=30.0)
    for name, scale in (("tangent", 1), ("normal", 1), ("height", 2), ("gap", 1)):
        reps = (2, 2, 1) if getattr(small, name).ndim == 3 else (2, 2)
        assert np.allclose(scale * getattr(big, name), np.tile(getattr(small, name), reps),
                           atol=1e-5), name


def test_periodic_with_resolution_not_multiple():
    # Odd sampling: the seam must still be no worse than interior steps.
    maps = woven_maps(plain(), (90, 70))
    for axis in (0, 1):
        _wrap_step_ok(maps.height, axis)
        _wrap_step_ok(maps.tangent, axis)


@pytest.mark.parametrize("w", [0.5, 0.8, 1.0])
def test_gap_fraction(w):
    maps = woven_maps(plain(), (RES, RES), yarn_width=w)
    texels_per_crossing = RES / 2
    expected = (1.0 - w) ** 2
    assert abs(float((maps.gap == 0).mean()) - expected) <= 1.0 / texels_per_crossing
    assert np.array_equal(maps.yarn_id == -1, maps.gap == 0)
    assert np.all(maps.albedo[maps.gap == 0] == 0)


def _centre(i: int, n: int, res: int) -> int:
    return int((i + 0.5) / n * res)


def test_yarn_id_at_crossings_matches_drawdown():
    dd = np.array([[1, 1, 0], [0, 1, 1], [1, 0, 1]], bool)  # 2/1 twill
    maps = woven_maps(dd, (96, 96))
    n_weft, n_warp = dd.shape
    for i in range(n_weft):
        for j in range(n_warp):
            r, c = _centre(i, n_weft, 96), _centre(j, n_warp, 96)
            expected = j if dd[i, j] else n_warp + i
            assert maps.yarn_id[r, c] == expected, (i, j)
            # The visible yarn is the upper one: it is higher than the crossing's mean.
            assert maps.height[r, c] > 0


def test_plain_ids_and_tangent_directions(plain_maps):
    dd = plain()
    for i in range(2):
        for j in range(2):
            r, c = _centre(i, 2, RES), _centre(j, 2, RES)
            t = plain_maps.tangent[r, c]
            if dd[i, j]:
                assert plain_maps.yarn_id[r, c] == j
                assert abs(t[1]) > abs(t[0]) > 0.3  # along v, twisted by 30 degrees
            else:
                assert plain_maps.yarn_id[r, c] == 2 + i
                assert abs(t[0]) > abs(t[1]) > 0.3  # along u
            assert abs(t[2]) < 0.1  # top of a crossing: flat


def test_twist_handedness_and_zero_twist():
    r, c = _centre(0, 2, RES), _centre(0, 2, RES)  # warp over weft here
    s_twist = woven_maps(plain(), RES, fibre_twist_deg=30.0).tangent[r, c]
    z_twist = woven_maps(plain(), RES, fibre_twist_deg=-30.0).tangent[r, c]
    none = woven_maps(plain(), RES, fibre_twist_deg=0.0).tangent[r, c]
    # Warp runs along +v; S twist tilts the top fibres toward -u, Z toward +u.
    assert s_twist[0] < -0.4 and z_twist[0] > 0.4
    assert abs(none[0]) < 1e-3 and none[1] > 0.99


def test_warp_dips_under_weft():
    # Along warp 0 (column centre), height at its over-crossing exceeds the height of the
    # (weft-covered) under-crossing region, and the axis slopes down between them.
    maps = woven_maps(plain(), RES, fibre_twist_deg=0.0)
    c = _centre(0, 2, RES)
    r_over, r_mid = _centre(0, 2, RES), RES // 2 - 1
    assert maps.yarn_id[r_mid, c] == 0
    assert maps.height[r_over, c] > maps.height[r_mid, c]
    assert maps.tangent[r_mid, c, 2] < -0.1  # descending toward the under-crossing at +v


def test_albedo_per_yarn(plain_maps):
    ids = plain_maps.yarn_id
    assert np.allclose(plain_maps.albedo[ids == 0], [0.9, 0.1, 0.1])
    assert np.allclose(plain_maps.albedo[ids == 1], [0.1, 0.9, 0.1])
    assert np.allclose(plain_maps.albedo[ids >= 2], [0.2, 0.3, 0.8])


@pytest.mark.parametrize("kwargs, words", [
    (dict(yarn_width=1.5), "yarn_width must be in (0, 1], got 1.5"),
    (dict(yarn_width=0.0), "yarn_width must be in (0, 1]"),
    (dict(yarn_height=-1.0), "yarn_height must be in (0, 2]"),
    (dict(yarn_height=float("nan")), "yarn_height"),
    (dict(fibre_twist_deg=120.0), "fibre_twist_deg must be in [-90, 90]"),
    (dict(fibre_twist_deg="30"), "fibre_twist_deg"),
    (dict(resolution=3), "resolution (texels along u) must be in [4, 8192]"),
    (dict(resolution=(64, 64, 3)), "resolution must be"),
    (dict(warp_colors=[[1, 0, 0]]), "warp_colors"),
    (dict(weft_colors=[2.0, 0, 0]), "weft_colors values must be in [0, 1]"),
])
def test_parameter_errors(kwargs, words):
    with pytest.raises(ParameterError) as info:
        woven_maps(plain(), **kwargs)
    assert words in str(info.value)


def test_large_tile_generates():
    # Speed is measured in `make bench`, not asserted here (shared, noisy machines).
    maps = woven_maps(plain(), 1024)
    assert maps.resolution == (1024, 1024)
    assert np.all(np.isfinite(maps.tangent))


# ---------------------------------------------------------------- slubs
def test_slub_factors_periodic_mean_one_and_peak_amplitude():
    period, n = 20.0, 4000
    pos = (np.arange(2 * n + 1)) * (period / n)          # two periods and one sample
    f, b = slub_factors(12, period, 0.5, pos, length_mm=(2.0, 6.0), spacing_mm=5.0, seed=3,
                        bumps=True)
    assert np.allclose(f[:, :n], f[:, n:2 * n]) and np.allclose(f[:, 0], f[:, -1])  # periodic
    one = f[:, :n]
    assert np.allclose(one.mean(axis=1), 1.0, atol=2e-3)   # the stated diameter is the mean
    slubby = b[:, :n].max(axis=1) > 0.999
    assert slubby.sum() >= 8                              # ~4 slubs per yarn expected
    assert np.allclose(one.max(axis=1)[slubby] / one.min(axis=1)[slubby], 1.5, rtol=1e-3)
    # Continuous (raised cosines of half-length >= 1 mm): no step beyond the steepest slope.
    assert np.abs(np.diff(f, axis=1)).max() <= 0.5 * (np.pi / 2.0) * (period / n) * 1.01
    assert np.array_equal(slub_factors(3, period, 0.0, pos), np.ones((3, pos.size)))
    # Irregular: slubs lie at different places on different yarns.
    assert np.corrcoef(f[:, :n])[np.triu_indices(12, 1)].max() < 0.9


def test_slubs_vary_the_yarn_width_along_it():
    """An open plain weave with a slubby warp: where no weft covers it, a warp end is as
    wide as its diameter there (slub_factors); the even weft keeps its width."""
    draft = Draft(np.tile(plain(), (16, 1)), warp_spacing=1.0, weft_spacing=1.0)  # 32 x 2 mm
    per = 40                                              # texels per mm
    maps = woven_maps(draft, (32 * per, 2 * per), yarn_width=0.4, slub=(0.5, 0.0),
                      slub_length_mm=(3.0, 8.0), slub_spacing_mm=8.0, slub_seed=7)
    y = (np.arange(32 * per) + 0.5) / per
    f = slub_factors(2, 32.0, 0.5, y, length_mm=(3.0, 8.0), spacing_mm=8.0, seed=[7, 0])
    clear = np.abs((y % 1.0) - 0.5) > 0.25                # rows beside the weft picks
    for end in (0, 1):
        width = (maps.yarn_id[:, end * per:(end + 1) * per] == end).sum(axis=1) / per
        assert np.allclose(width[clear], 0.4 * f[end][clear], atol=1.5 / per)
        assert width[clear].max() / width[clear].min() > 1.3     # it does vary along the yarn
    picks = maps.yarn_id[:, :per] >= 2
    widths = picks.reshape(32, per, per)[..., 0].sum(axis=1)  # weft rows in column 0 per pick
    assert np.ptp(widths[::2]) <= 1                        # even weft


def test_slubby_maps_are_seamless():
    maps = woven_maps(np.tile(plain(), (6, 6)), (192, 192), slub=0.6, slub_length_mm=(0.5, 3.0),
                      slub_spacing_mm=2.0, slub_seed=1)
    assert maps.meta["slub"] == [0.6, 0.6]
    # The tile's edge is a thread boundary like the 11 inside it: its step (the mean over
    # the edge) is one of theirs, no seam (tangents flip between warp and weft anyway).
    for axis in (0, 1):
        for name in ("height", "tangent", "normal", "albedo"):
            a = np.asarray(getattr(maps, name), dtype=float)
            wrapped = np.concatenate([a, np.take(a, [0], axis=axis)], axis=axis)
            steps = np.abs(np.diff(wrapped, axis=axis))
            steps = steps.reshape(steps.shape[:2] + (-1,)).sum(axis=-1).mean(axis=1 - axis)
            boundaries = steps[16 - 1::16]                   # 16 texels per thread
            assert boundaries[-1] <= 1.25 * boundaries[:-1].max() + 1e-6, (name, axis, boundaries)


def test_slub_parameter_errors():
    for kwargs, words in ((dict(slub=-0.1), "slub must be in [0, 4]"),
                          (dict(slub=(0.1, 0.2, 0.3)), "slub must be a number or a (warp, weft) pair"),
                          (dict(slub_length_mm=(3.0, 2.0)), "slub_length_mm must be (shortest, longest)"),
                          (dict(slub_spacing_mm=0.0), "slub_spacing_mm"),
                          (dict(slub_seed=1.5), "slub_seed must be an integer"),
                          (dict(slub_tone=3.0), "slub_tone must be in [0.5, 2]")):
        with pytest.raises(ParameterError) as info:
            woven_maps(plain(), 16, **kwargs)
        assert words in str(info.value)


# ---------------------------------------------------------------- previews
def test_previews(plain_maps, tmp_path):
    paths = write_previews(plain_maps, tmp_path / "prev")
    names = {p.name for p in paths}
    assert names == {"tangent.png", "normal.png", "height.png", "gap.png", "yarn_id.png",
                     "albedo.png", "contact_sheet.png"}
    for p in paths:
        with Image.open(p) as img:
            if p.name != "contact_sheet.png":
                assert img.size == (RES, RES)
    with Image.open(tmp_path / "prev" / "yarn_id.png") as img:
        ids = np.asarray(img.convert("RGB"))
    colours = {tuple(ids[r, c]) for r, c in [(32, 32), (32, 96), (96, 32), (96, 96)]}
    assert len(colours) == 4 and (0, 0, 0) not in colours
    assert tuple(ids[0, 0]) == (0, 0, 0)  # tile corner is a gap
    with Image.open(tmp_path / "prev" / "contact_sheet.png") as img:
        assert img.width > 6 * RES and img.height > RES
    with pytest.raises(MapsError, match="overwrite"):
        write_previews(plain_maps, tmp_path / "prev")
    write_previews(plain_maps, tmp_path / "prev", overwrite=True)


# ---------------------------------------------------------------- builtins
def test_builtin_plain_and_cache():
    assert "plain" in BUILTIN_PATTERNS
    a = resolve_pattern("plain")
    assert a.resolution == (128, 128) and a.meta["tile_size_mm"] == [1.0, 1.0]
    assert resolve_pattern("plain") is a
    assert resolve_pattern("plain", 64).resolution == (64, 64)


def test_default_resolution_follows_threads_within_bounds():
    """32 texels per thread within [128, 320] (issue 22: the tables' build and disk), knits 64
    per wale within [64, 320], but at least 8 per thread or wale, up to 1024."""
    from types import SimpleNamespace

    from mscloth.maps.builtin import default_resolution
    threads = {2: 128, 5: 160, 8: 256, 24: 320, 64: 512, 200: 1024}
    assert {n: default_resolution(SimpleNamespace(n_warp=n)) for n in threads} == threads
    wales = {1: 64, 3: 192, 8: 320, 100: 800}
    assert {n: default_resolution(SimpleNamespace(n_wales=n)) for n in wales} == wales


def test_resolve_directory(plain_maps, tmp_path):
    plain_maps.save(tmp_path / "m")
    loaded = resolve_pattern(str(tmp_path / "m"))
    assert np.array_equal(loaded.tangent, plain_maps.tangent)
    assert resolve_pattern(str(tmp_path / "m")) is loaded
    with pytest.raises(PatternError, match="resolution"):
        resolve_pattern(str(tmp_path / "m"), RES // 2)


def test_resolve_directory_reloads_after_change(plain_maps, tmp_path):
    plain_maps.save(tmp_path)
    first = resolve_pattern(str(tmp_path))
    other = woven_maps(plain(), RES, yarn_width=0.5)
    other.save(tmp_path, overwrite=True)
    os.utime(tmp_path / "maps.npz", ns=(time.time_ns(), time.time_ns() + 10**9))
    second = resolve_pattern(str(tmp_path))
    assert second is not first and second.meta["yarn_width"] == 0.5


def test_resolve_unknown():
    with pytest.raises(PatternError) as info:
        resolve_pattern("foo")
    assert "unknown pattern 'foo'" in str(info.value) and "plain" in str(info.value)


# ------------------------------------------------------------ resolutions that fit the tile
def _draft(ends: int, picks: int, weft_spacing: float | None = None) -> Draft:
    """A plain-like draft of ``ends`` x ``picks`` (checkerboard drawdown)."""
    i, j = np.indices((picks, ends))
    return Draft((i + j) % 2 == 0, weft_spacing=weft_spacing)


def test_default_resolution_fits_wide_and_tall_drafts():
    """The default was 8 texels per end capped at 1024 and knew nothing of the height: a
    600-end draft (2 texels per end: 1200 at least) and a 4-end x 1000-pick one (a tile 250
    times as tall as wide: at most 32 wide for 8192 tall) got widths their tile refused."""
    from mscloth.maps.builtin import default_resolution
    from mscloth.maps.generator_support import tile_resolution, width_range
    from mscloth.maps.woven import tile_shape

    wide, tall = _draft(600, 600), _draft(4, 1000)
    assert default_resolution(wide) == 1200
    assert tile_resolution(1200, *tile_shape(wide)) == (1200, 1200)
    assert width_range(*tile_shape(tall)[:3]) == (8, 32)
    assert default_resolution(tall) == 32
    assert woven_maps(tall, default_resolution(tall)).resolution == (8000, 32)


def test_default_resolution_of_a_tile_nothing_fits_says_why_without_a_number():
    """No width holds 2 ends whose picks are spaced 3000 times wider (any width of 4 or more
    makes the tile over 8192 tall), nor 3000 courses at 4 texels each: the error says so
    and what to change, and quotes no resolution the caller never gave."""
    from mscloth.errors import ResolutionError
    from mscloth.maps.builtin import default_resolution
    from mscloth.patterns.knit import KnitPattern

    with pytest.raises(ResolutionError) as info:
        default_resolution(_draft(2, 2, weft_spacing=1500.0))
    text = str(info.value)
    assert text.startswith("no resolution (texels along u) fits this tile: at its aspect H/W = 3000, a tile as wide as its 2 warp ends "
                           "need (4 texels) would be 12000 texels tall")
    assert "fewer weft picks per repeat, or weft picks spaced more closely, would fit" in text
    assert "got" not in text and info.value.low > info.value.high
    with pytest.raises(ResolutionError) as info:
        default_resolution(KnitPattern(np.ones((3000, 1), dtype=bool)))
    assert "4 texels for each of the 3000 courses" in str(info.value)
    assert "a repeat of at most 2048 courses fits" in str(info.value) and "got" not in str(info.value)


def test_largest_tile_side_is_the_bsdfs():
    """The cloth BSDF's resolution takes [8, 8192]; the generators agree."""
    from mscloth.errors import ResolutionError
    from mscloth.maps.generator_support import MAX_RESOLUTION

    assert MAX_RESOLUTION == 8192
    # (Cheap tiles: 4096 ends x 2 picks is 8192 x 4 texels at its least.)
    with pytest.raises(ResolutionError, match=r"must be in \[8192, 8192\] for this tile, got 8193: a tile side "
                                              r"has at most 8192 texels"):
        woven_maps(_draft(4096, 2), 8193)
    with pytest.raises(ResolutionError, match=r"resolution H must be in \[4, 8192\]"):
        woven_maps(plain(), (8193, 4))


def test_one_thread_or_stitch_is_singular():
    from mscloth.maps.knit import knit_maps
    from mscloth.patterns.knit import jersey

    with pytest.raises(ParameterError) as info:
        knit_maps(jersey(), 3)  # one course, one wale
    assert "4 texels for its 1 course" in str(info.value) and "each of the 1" not in str(info.value)


def test_maps_that_would_not_fit_in_memory_are_refused_before_any_array(monkeypatch):
    """At ~640 bytes per texel a tile is refused, in one line with the estimate and what is
    available, when it needs more than the system has (no MemoryError, no OOM killer); the
    BSDF's path (resolve_pattern) gets the same error."""
    from mscloth.errors import ResolutionError
    from mscloth.maps import generator_support
    from mscloth.maps.knit import knit_maps
    from mscloth.patterns.knit import jersey

    monkeypatch.setattr(generator_support, "available_memory", lambda: 200 << 20)
    with pytest.raises(ResolutionError) as info:
        woven_maps(plain(), 1024)
    text = str(info.value)
    assert text.startswith("maps of 1024x1024 texels need about 704 MiB of memory to generate")
    assert "but 200 MiB is available: resolution 472 (texels along u) or less fits" in text
    assert "\n" not in text and info.value.largest == 472 and info.value.low is None
    with pytest.raises(ResolutionError, match="200 MiB is available"):
        resolve_pattern("twill-2-1", 1000)
    with pytest.raises(ResolutionError, match="200 MiB is available"):
        knit_maps(jersey(), 1024)
    # The suggestion holds, and what fits is made as before.
    assert woven_maps(plain(), 472).resolution == (472, 472)
    monkeypatch.setattr(generator_support, "available_memory", lambda: 10 << 20)
    with pytest.raises(ResolutionError, match=r"no resolution fits \(this tile needs at least 4 texels along u\)"):
        woven_maps(plain(), 8)


@pytest.mark.parametrize("kwargs, texels, suggested", [
    (dict(gap_fraction=0.99), "the warp yarn is 0.32 texels wide (gap fraction 1.000 instead of the requested 0.990)", 798),
    (dict(yarn_width=0.01), "the warp yarn is 0.64 texels wide (gap fraction 1.000)", 400),
])
def test_a_yarn_narrower_than_a_texel_warns(kwargs, texels, suggested):
    """Sampled at texel centres, a yarn under a texel wide is mostly missed: an invisible
    cloth (gap fraction 1) needs a warning naming the resolution that shows the yarn."""
    from mscloth.maps.generator_support import MapsWarning

    with pytest.warns(MapsWarning) as caught:
        maps = woven_maps(plain(), 128, **kwargs)
    assert float(maps.gap.mean()) == 0.0
    text = str(caught[0].message)
    assert texels in text and f"resolution {suggested} (texels along u) or more resolves it" in text
    assert caught[0].message.naming("--res").endswith(f"--res {suggested} or more resolves it")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        maps = woven_maps(plain(), suggested, **kwargs)  # the suggestion does
    assert 0.0 < float(maps.gap.mean())


def test_a_gap_fraction_far_from_the_requested_one_warns():
    """Yarns 2.3 texels wide hit 2 or 3 texel centres: 0.56 instead of 0.5."""
    from mscloth.maps.generator_support import MapsWarning

    with pytest.warns(MapsWarning, match=r"gap fraction 0\.562 instead of the requested 0\.500\): "
                                         r"resolution 40 \(texels along u\) or more"):
        woven_maps(plain(), 16, gap_fraction=0.5)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        woven_maps(plain(), 40, gap_fraction=0.5)
        woven_maps(plain(), 128, gap_fraction=0.25)
