"""Knitted fabrics: stitch patterns (mscloth.patterns.knit) and their maps (mscloth.maps.knit)."""
import math

import numpy as np
import pytest

from mscloth.errors import ParameterError, PatternError
from mscloth.maps.cloth_maps import ClothMaps
from mscloth.maps.knit import knit_maps, srgb_to_linear
from mscloth.patterns.knit import (KnitPattern, garter, jersey, reverse_jersey, rib, seed)

A = 0.8          # default loop_aspect: course spacing / wale spacing
H_LOOP = 0.6     # loop half-height in wale units: loop_height (1.5) * A / 2


# ---------------------------------------------------------------- patterns
def test_striped_constructors():
    red, blue, green = [1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]
    p = rib(2, 2, course_colors=[red, blue, green])
    assert p.stitches.shape == (3, 4) and np.allclose(p.course_colors[2], green)
    p = rib(2, 2, wale_colors=[red, blue])
    assert p.stitches.shape == (1, 4) and np.allclose(p.wale_colors[:, 2], [0, 1, 0, 1])
    p = garter(course_colors=[red, blue, green])
    assert np.array_equal(p.stitches[:, 0], [1, 0, 1, 0, 1, 0])
    assert np.allclose(p.course_colors[3], red)
    with pytest.raises(PatternError, match="course_colors"):
        jersey(course_colors=[[1.0, 0.0]])


def test_named_patterns():
    assert np.array_equal(jersey().stitches, [[1]])
    assert np.array_equal(reverse_jersey().stitches, [[0]])
    assert np.array_equal(rib(1, 1).stitches, [[1, 0]])
    assert np.array_equal(rib(2, 2).stitches, [[1, 1, 0, 0]])
    assert np.array_equal(rib(3, 1).stitches, [[1, 1, 1, 0]])
    assert np.array_equal(garter().stitches, [[1], [0]])
    assert np.array_equal(seed().stitches, [[1, 0], [0, 1]])
    big = rib(2, 2).tiled(3, 2)
    assert big.stitches.shape == (3, 8) and np.array_equal(big.stitches[2], [1, 1, 0, 0] * 2)
    assert (big.n_courses, big.n_wales) == (3, 8)


def test_pattern_accepts_bools_and_colours():
    p = KnitPattern([[True, False]], course_colors=[0.2, 0.4, 0.6])
    assert p.stitches.dtype == np.int8 and np.array_equal(p.stitches, [[1, 0]])
    assert p.course_colors.shape == (1, 3)
    assert np.allclose(p.stitch_colors(), [[[0.2, 0.4, 0.6]] * 2])
    # Course colours win over wale colours (a course is one yarn in weft knitting).
    both = KnitPattern([[1, 0]], course_colors=[[1, 0, 0]], wale_colors=[[0, 1, 0], [0, 0, 1]])
    assert np.allclose(both.stitch_colors(), [[[1, 0, 0], [1, 0, 0]]])
    wales = KnitPattern([[1, 0]], wale_colors=[[0, 1, 0], [0, 0, 1]])
    assert np.allclose(wales.stitch_colors(), [[[0, 1, 0], [0, 0, 1]]])
    assert np.allclose(KnitPattern([[1]]).stitch_colors(), 1.0)
    tiled = both.tiled(2, 3)
    assert tiled.course_colors.shape == (2, 3) and tiled.wale_colors.shape == (6, 3)


@pytest.mark.parametrize("kwargs, words", [
    (dict(stitches=[[2, 1]]), "KnitPattern.stitches: expected only the values 0"),
    (dict(stitches=[1, 0]), "KnitPattern.stitches: expected a 2-D array"),
    (dict(stitches=np.zeros((0, 3))), "KnitPattern.stitches: expected a non-empty"),
    (dict(stitches=[["k", "p"]]), "KnitPattern.stitches"),
    (dict(stitches=[[1, 0], [1]]), "KnitPattern.stitches"),
    (dict(stitches=[[1, 0]], course_colors=[[1, 0, 0], [0, 1, 0]]), "KnitPattern.course_colors"),
    (dict(stitches=[[1, 0]], wale_colors=[[1, 0, 0]]), "KnitPattern.wale_colors"),
    (dict(stitches=[[1, 0]], wale_colors=[1.5, 0, 0]), "KnitPattern.wale_colors: expected sRGB"),
    (dict(stitches=[[1]], name=3), "KnitPattern.name"),
    (dict(stitches=[[1]], meta=[]), "KnitPattern.meta"),
])
def test_pattern_errors_name_field(kwargs, words):
    with pytest.raises(PatternError) as info:
        KnitPattern(**kwargs)
    assert words in str(info.value)


def test_constructor_errors():
    with pytest.raises(PatternError, match="k"):
        rib(0, 1)
    with pytest.raises(PatternError, match="p"):
        rib(1, 1.5)
    with pytest.raises(PatternError, match="courses"):
        jersey().tiled(0, 1)
    with pytest.raises(PatternError, match="KnitPattern or a stitch array"):
        knit_maps("jersey")


# ---------------------------------------------------------------- maps: validity
def _texel(x: float, y: float, maps: ClothMaps, n_courses: int, n_wales: int):
    """Texel (row, column) holding the point (x, y) in wale units (y = course spacing * A)."""
    h, w = maps.resolution
    return int(y / (n_courses * A) * h), int(x / n_wales * w)


@pytest.mark.parametrize("pattern", [jersey(), rib(2, 2), garter(), seed(), reverse_jersey()])
def test_maps_valid(pattern):
    maps = knit_maps(pattern, 64)
    assert isinstance(maps, ClothMaps)
    nc, nw = pattern.stitches.shape
    assert maps.resolution == (round(64 * nc * A / nw), 64)   # int: width, square texels
    for name in ("tangent", "normal"):
        assert np.allclose(np.linalg.norm(getattr(maps, name), axis=-1), 1.0, atol=1e-5), name
    assert np.all(maps.normal[..., 2] > 0)
    assert np.array_equal(maps.yarn_id == -1, maps.gap == 0)
    assert set(np.unique(maps.yarn_id)) <= set(range(-1, nc))
    assert np.all(maps.albedo[maps.gap == 0] == 0)
    # Yarn surfaces are above the hole floor, never above the front layer's top (d + r),
    # raised by the wale's rib offset (rib_depth 1: yarn_width / 2 for a rib's knit wales).
    floor = float(maps.height.min())
    assert np.all(maps.height[maps.gap == 1] > floor)
    kind = (2.0 * pattern.stitches - 1.0).mean(axis=0)
    assert maps.height.max() <= (0.225 + 0.225 + 0.5 * 0.45 * (kind - kind.mean()).max()) / nw + 1e-6
    assert maps.meta["generator"] == "knit"
    assert maps.meta["stitches"] == pattern.stitches.tolist()
    assert maps.meta["tile_aspect"] == pytest.approx(nc * A / nw)
    assert maps.meta["tile_size_mm"] == pytest.approx([nw * 1.0, nc * A])


def test_stitch_array_accepted_directly():
    a = knit_maps([[1, 0]], (32, 40))
    b = knit_maps(rib(1, 1), (32, 40))
    assert np.array_equal(a.height, b.height) and np.array_equal(a.tangent, b.tangent)


# ---------------------------------------------------------------- seamless
@pytest.mark.parametrize("pattern", [jersey(), rib(2, 1), seed()])
def test_seamless_exact_period(pattern):
    # The maps of a 2x2 repeat at twice the resolution equal the tile laid 2x2, seams
    # included (heights halve: they are in tile widths and the big tile is twice as wide).
    nc, nw = pattern.stitches.shape
    res = (12 * nc, 20 * nw)
    small = knit_maps(pattern, res)
    big = knit_maps(pattern.tiled(2, 2), (2 * res[0], 2 * res[1]))
    for name, scale in (("tangent", 1), ("normal", 1), ("height", 2), ("gap", 1),
                        ("albedo", 1)):
        reps = (2, 2, 1) if getattr(small, name).ndim == 3 else (2, 2)
        assert np.allclose(scale * getattr(big, name), np.tile(getattr(small, name), reps),
                           atol=1e-5), name
    ids = np.where(big.yarn_id >= 0, big.yarn_id % nc, -1)
    assert np.array_equal(ids, np.tile(small.yarn_id, (2, 2)))


def _wrap_step_ok(a: np.ndarray, axis: int) -> None:
    """The step across the tile seam is no larger than the largest interior step."""
    interior = np.abs(np.diff(a, axis=axis))
    seam = np.abs(np.take(a, 0, axis=axis) - np.take(a, -1, axis=axis))
    assert seam.max() <= interior.max() + 1e-6


def test_periodic_with_odd_resolution():
    maps = knit_maps(rib(1, 1), (45, 71))
    for axis in (0, 1):
        _wrap_step_ok(maps.height, axis)
        _wrap_step_ok(maps.tangent, axis)
        _wrap_step_ok(maps.normal, axis)


# ---------------------------------------------------------------- geometry
def test_gaps_are_texels_farther_than_a_yarn_radius_from_every_centreline():
    # Independent check of the nearest-point search: dense polylines of every course's
    # centreline (the curve of the module docstring) against the gap map.
    pattern = rib(1, 1).tiled(2, 1)
    nc, nw = pattern.stitches.shape
    maps = knit_maps(pattern, (48, 80), yarn_width=0.4)
    h_rows, w_cols = maps.resolution
    amp = 0.5 * (1.0 + 2.0 * math.pi * H_LOOP * math.tan(math.radians(25.0)))
    T = np.linspace(-2 * math.pi, 2 * math.pi * (nw + 2), 4000 * (nw + 4))
    cx = (T + amp * np.sin(2 * T)) / (2 * math.pi)
    cy = H_LOOP * np.cos(T)
    X = (np.arange(w_cols) + 0.5) * nw / w_cols
    Y = (np.arange(h_rows) + 0.5) * nc * A / h_rows
    dist = np.full((h_rows, w_cols), np.inf)
    for k in range(-2, nc + 2):
        for r in range(h_rows):
            dy = Y[r] - (k + 0.5) * A - cy
            if np.abs(dy).min() > 0.3:
                continue
            d2 = (X[:, None] - cx[None, :]) ** 2 + dy[None, :] ** 2
            dist[r] = np.minimum(dist[r], np.sqrt(d2.min(axis=1)))
    clear = np.abs(dist - 0.2) > 1e-3            # away from the yarn edge
    assert np.array_equal((dist < 0.2)[clear], (maps.gap == 1)[clear])
    assert (maps.gap == 0).any()


def test_tangent_follows_the_nearest_centreline_point():
    # With no twist the in-plane fibre direction is the centreline direction at the nearest
    # point of the visible course (found here by brute force over dense samples). 200
    # columns per wale put texels within 1/400 of the loop's mirror lines x = 0 and 1/2,
    # where the left and right legs (or sinker halves) are almost equally near.
    pattern = jersey().tiled(2, 1)
    maps = knit_maps(pattern, (48, 200), fibre_twist_deg=0.0)
    amp = 0.5 * (1.0 + 2.0 * math.pi * H_LOOP * math.tan(math.radians(25.0)))
    T = np.linspace(-math.pi, 3 * math.pi, 8001)
    cx = (T + amp * np.sin(2 * T)) / (2 * math.pi)
    cy = H_LOOP * np.cos(T)
    dx, dy = 1.0 + 2.0 * amp * np.cos(2 * T), -2.0 * math.pi * H_LOOP * np.sin(T)
    h_rows, w_cols = maps.resolution
    x = (np.arange(w_cols) + 0.5) / w_cols
    errors = []
    for r in range(h_rows):
        y = (r + 0.5) * 2 * A / h_rows
        k = maps.yarn_id[r]
        best_d2 = np.full(w_cols, np.inf)
        best_i = np.zeros(w_cols, int)
        for shift in (-2, 0, 2):               # the course and its copies one repeat away
            yc = (k + shift + 0.5) * A            # (w_cols,)
            d2 = (x[:, None] - cx[None, :]) ** 2 + (y - yc[:, None] - cy[None, :]) ** 2
            i = np.argmin(d2, axis=1)
            d2 = d2[np.arange(w_cols), i]
            better = d2 < best_d2
            best_d2, best_i = np.where(better, d2, best_d2), np.where(better, i, best_i)
        ref = np.stack([dx[best_i], dy[best_i]], -1)
        ref /= np.linalg.norm(ref, axis=-1, keepdims=True)
        t = maps.tangent[r, :, :2] / np.linalg.norm(maps.tangent[r, :, :2], axis=-1)[:, None]
        err = np.abs(ref[:, 0] * t[:, 1] - ref[:, 1] * t[:, 0])
        errors.append(err[k >= 0])
    errors = np.concatenate(errors)
    assert np.mean(errors < math.sin(math.radians(1.0))) > 0.999
    assert np.median(errors) < 1e-3


@pytest.mark.parametrize("tilt", [15.0, 25.0, 35.0])
def test_jersey_legs_form_a_v(tilt):
    # Leg midpoints of the loop of course 1: (0.25, centre) and (0.75, centre), wale units.
    pattern = jersey().tiled(3, 1)
    maps = knit_maps(pattern, (240, 100), fibre_twist_deg=0.0, leg_tilt_deg=tilt)
    y = 1.5 * A
    left = maps.tangent[_texel(0.25, y, maps, 3, 1)]
    right = maps.tangent[_texel(0.75, y, maps, 3, 1)]
    assert maps.yarn_id[_texel(0.25, y, maps, 3, 1)] == 1
    assert maps.yarn_id[_texel(0.75, y, maps, 3, 1)] == 1
    # Toward the head (-v) the left leg leans to -u and the right leg to +u: a "V" in the
    # preview image, where +v points down.
    assert left[0] * left[1] > 0 and right[0] * right[1] < 0
    for t in (left, right):
        angle = math.degrees(math.atan2(abs(t[0]), abs(t[1])))
        assert angle == pytest.approx(tilt, abs=2.0)
        assert abs(t[2]) < 0.05                  # leg midpoint: flat, on the front layer


def test_jersey_intermeshing_depth():
    # Knit: a loop's head lies behind the legs of the course above (-v), and its sinkers
    # behind the legs of the course below. Purl (reverse jersey): heads and sinkers in front.
    y_head, y_sinker = 1.5 * A - H_LOOP, 1.5 * A + H_LOOP
    knit = knit_maps(jersey().tiled(3, 1), (240, 100), fibre_twist_deg=0.0)
    purl = knit_maps(reverse_jersey().tiled(3, 1), (240, 100), fibre_twist_deg=0.0)
    assert knit.yarn_id[_texel(0.5, y_head, knit, 3, 1)] == 0
    assert knit.yarn_id[_texel(0.0, y_sinker, knit, 3, 1)] == 2
    for x, y in ((0.5, y_head), (0.02, y_sinker)):
        rc = _texel(x, y, purl, 3, 1)
        assert purl.yarn_id[rc] == 1
        assert abs(purl.tangent[rc][0]) > 0.95    # head / sinker arcs run along u
        assert purl.height[rc] == pytest.approx(0.45, abs=0.01)   # front layer top: d + r
    # Legs sit on the front layer in jersey, on the back layer in reverse jersey.
    rc = _texel(0.25, 1.5 * A, knit, 3, 1)
    assert knit.height[rc] > 0.4 and purl.height[rc] < 0.05


def test_garter_heads_follow_the_stitch_above():
    # A loop's head is intermeshed with the course above (-v): garter course 2 (knit) lies
    # under purl course 1, so its head is in front (a purl ridge); purl course 1's head lies
    # under knit course 0, so it is hidden behind course 0's legs.
    maps = knit_maps(garter().tiled(2, 1), (320, 100), fibre_twist_deg=0.0)
    rc = _texel(0.5, 2.5 * A - H_LOOP, maps, 4, 1)
    assert maps.yarn_id[rc] == 2
    assert abs(maps.tangent[rc][0]) > 0.95
    assert maps.height[rc] == pytest.approx(0.45, abs=0.01)
    assert maps.yarn_id[_texel(0.5, 1.5 * A - H_LOOP, maps, 4, 1)] == 0


def _centre_region(maps, i, j, nc, nw, frac=0.5):
    h, w = maps.resolution
    r0, r1 = int((i + 0.5 - frac / 2) * h / nc), int((i + 0.5 + frac / 2) * h / nc)
    c0, c1 = int((j + 0.5 - frac / 2) * w / nw), int((j + 0.5 + frac / 2) * w / nw)
    return (slice(r0, r1), slice(c0, c1))


def test_rib_purl_stitches_show_u_running_yarn():
    pattern = rib(1, 1)
    maps = knit_maps(pattern, (96, 240), fibre_twist_deg=0.0, rib_depth=0.0)
    t, gap = maps.tangent, maps.gap == 1
    purl = _centre_region(maps, 0, 1, 1, 2)
    knit = _centre_region(maps, 0, 0, 1, 2)
    along_u = np.abs(t[..., 0]) > np.abs(t[..., 1])
    assert along_u[purl][gap[purl]].mean() > 0.75
    assert along_u[knit][gap[knit]].mean() < 0.1
    assert np.abs(t[purl][..., 0]).mean() > 1.5 * np.abs(t[purl][..., 1]).mean()
    # The purl bump reaches the front layer (top at d + r = 0.45 wale = 0.225 tile widths).
    assert maps.height[purl].max() == pytest.approx(0.225, abs=0.005)


def _wale_tops(maps, nw):
    """The 90th percentile of the height (wale units) in the middle half of each wale."""
    h = maps.height * nw
    per = maps.resolution[1] // nw
    return np.array([np.percentile(h[:, j * per + per // 4:(j + 1) * per - per // 4], 90)
                     for j in range(nw)])


def test_rib_knit_wales_stand_proud_of_purl_wales():
    """A rib draws together: its knit wales stand out, its purl wales recede by rib_depth
    yarn widths (before rib_depth both lay at the front layer's top: no relief)."""
    for depth in (0.5, 1.0, 2.0):
        tops = _wale_tops(knit_maps(rib(2, 2).tiled(4, 1), 256, rib_depth=depth), 4)
        relief = tops[:2].min() - tops[2:].max()
        assert relief == pytest.approx(depth * 0.45, abs=0.05 * 0.45 + 0.02), (depth, tops)
    default = _wale_tops(knit_maps(rib(2, 2).tiled(4, 1), 256), 4)
    assert default[:2].min() - default[2:].max() >= 0.9 * 0.45
    flat = _wale_tops(knit_maps(rib(2, 2).tiled(4, 1), 256, rib_depth=0.0), 4)
    assert abs(flat[:2].mean() - flat[2:].mean()) < 0.02
    # Patterns whose wales all mix knit and purl alike have no rib relief.
    for pattern in (jersey(), garter(), seed(), reverse_jersey()):
        a, b = knit_maps(pattern, 64), knit_maps(pattern, 64, rib_depth=3.0)
        assert np.array_equal(a.height, b.height) and np.array_equal(a.tangent, b.tangent)


def test_gap_fraction_and_yarn_width():
    fractions = [float((knit_maps(jersey(), (80, 100), yarn_width=w).gap == 0).mean())
                 for w in (0.25, 0.3, 0.35, 0.4, 0.45)]
    assert all(0.0 < f < 0.5 for f in fractions)
    assert all(a > b for a, b in zip(fractions, fractions[1:])), fractions
    # Thick yarns close every hole.
    assert float((knit_maps(jersey(), (80, 100), yarn_width=0.8).gap == 0).mean()) == 0.0


def test_twist_rotates_tangent_about_the_yarn_surface_normal():
    # At a leg midpoint on the yarn's centreline the cross-section normal is +z, so the
    # twist is an in-plane rotation by psi: counter-clockwise (x toward y) for psi > 0, the
    # S-twist convention of woven maps.
    pattern = jersey().tiled(3, 1)
    rc = _texel(0.25, 1.5 * A, knit_maps(pattern, (240, 100)), 3, 1)
    base = knit_maps(pattern, (240, 100), fibre_twist_deg=0.0).tangent[rc]
    for psi in (30.0, -30.0, 60.0):
        t = knit_maps(pattern, (240, 100), fibre_twist_deg=psi).tangent[rc]
        angle = math.degrees(math.atan2(base[0] * t[1] - base[1] * t[0], float(base @ t)))
        assert angle == pytest.approx(psi, abs=3.0)


def test_colours_land_in_albedo():
    pattern = jersey(course_colors=[[1.0, 0.0, 0.0], [0.0, 0.5, 1.0]])   # 2-course stripes
    assert pattern.stitches.shape == (2, 1)
    maps = knit_maps(pattern, (64, 40))
    assert srgb_to_linear(0.5) == pytest.approx(0.21404, abs=1e-4)
    assert np.allclose(maps.albedo[maps.yarn_id == 0], [1.0, 0.0, 0.0])
    assert np.allclose(maps.albedo[maps.yarn_id == 1], [0.0, 0.21404, 1.0], atol=1e-4)
    assert np.allclose(maps.meta["stitch_colors"][1][0], [0.0, 0.21404, 1.0], atol=1e-4)

    # Wale colours colour stitches by column; course colours would override them.
    wales = KnitPattern([[1, 0]], wale_colors=[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]).tiled(3, 1)
    maps = knit_maps(wales, (240, 200), fibre_twist_deg=0.0)
    assert np.allclose(maps.albedo[_texel(0.25, 1.5 * A, maps, 3, 2)], [1, 0, 0])   # knit leg
    assert np.allclose(maps.albedo[_texel(1.5, 1.5 * A, maps, 3, 2)], [0, 1, 0])    # purl bump
    both = KnitPattern([[1, 0]], course_colors=[[0.0, 0.0, 1.0]],
                       wale_colors=[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    maps = knit_maps(both, (48, 120))
    assert np.allclose(maps.albedo[maps.gap == 1], [0, 0, 1])


@pytest.mark.parametrize("kwargs, words", [
    (dict(yarn_width=0.0), "yarn_width must be in (0, 1]"),
    (dict(yarn_width=1.5), "yarn_width must be in (0, 1], got 1.5"),
    (dict(loop_aspect=5.0), "loop_aspect must be in [0.3, 3]"),
    (dict(loop_height=0.5), "loop_height must be in [1, 3]"),
    (dict(leg_tilt_deg=60.0), "leg_tilt_deg must be in [0, 45]"),
    (dict(leg_tilt_deg=44.0), "leg_tilt_deg 44 is too large for loop_aspect 0.8"),
    (dict(leg_tilt_deg=20.0, loop_aspect=3.0, loop_height=3.0), "at most 7.3 degrees"),
    (dict(yarn_height=-1.0), "yarn_height must be in (0, 2]"),
    (dict(yarn_height=float("nan")), "yarn_height"),
    (dict(fibre_twist_deg=120.0), "fibre_twist_deg must be in [-90, 90]"),
    (dict(fibre_twist_deg="30"), "fibre_twist_deg"),
    (dict(wale_spacing_mm=0.0), "wale_spacing_mm"),
    (dict(rib_depth=-0.5), "rib_depth must be in [0, 4]"),
    (dict(resolution=3), "resolution (texels along u) must be in [5, 8192]"),
    (dict(resolution=(64, 2)), "resolution W must be in [4,"),
    (dict(resolution=(64, 64, 3)), "resolution must be"),
    (dict(resolution=True), "resolution must be"),
])
def test_parameter_errors(kwargs, words):
    with pytest.raises(ParameterError) as info:
        knit_maps(jersey(), **kwargs)
    assert words in str(info.value)


def test_large_tile_generates():
    # Speed is measured elsewhere, not asserted here (shared, noisy machines).
    maps = knit_maps(jersey(), (1024, 1024))
    assert maps.resolution == (1024, 1024)
    assert np.all(np.isfinite(maps.tangent)) and 0.0 < float((maps.gap == 0).mean()) < 0.5
