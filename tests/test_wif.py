"""WIF reader: real handweaving.net files, small drafts with known drawdowns, and malformed files.

Expected counts and colours of the real files are read off the files by eye and hard-coded
here (they are the spec); their drawdowns are recomputed with a deliberately naive
configparser + nested-loop implementation that shares no code with the reader.
"""
from __future__ import annotations

import configparser
import os
import random
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from mscloth.errors import PatternError
from mscloth.patterns.draft import DEFAULT_SPACING_MM, Draft
from mscloth.patterns.wif import parse_wif, read_wif

ROOT = Path(__file__).resolve().parents[1]
T, F = True, False

# Most small drafts here give no Spacing= (and some weave oddly on purpose): their WifWarnings
# are expected. The tests of the warnings themselves use pytest.warns / record them, which
# shows every warning whatever this filter says.
pytestmark = pytest.mark.filterwarnings("ignore::mscloth.patterns.wif.WifWarning")


# The project's shared data sits beside the checkout (../shared), in CI too.
WIF_DIR = Path(os.environ.get("MSCLOTH_WIF_DIR") or ROOT.parent / "shared" / "data" / "wif")


def needs_data(test):
    """Real-file tests fail (never skip) when the shared WIF files are missing."""
    return test


def test_real_wif_files_are_present():
    assert (WIF_DIR / "2229.wif").is_file(), f"shared WIF drafts not found in {WIF_DIR} (set MSCLOTH_WIF_DIR)"

GREEN_101 = (0 / 255, 101 / 255, 0 / 255)
GREEN_102 = (0 / 255, 102 / 255, 0 / 255)
BLUE = (51 / 255, 0 / 255, 255 / 255)
WHITE = (1.0, 1.0, 1.0)

# name: (warp ends, weft picks, shafts, treadles, warp colours, weft colours) -- from the files.
REAL = {
    "2229": (24, 24, 3, 4, [GREEN_101] * 24, [WHITE] * 24),
    # Lists colours for threads 1-2 only although Threads=3: thread 3 falls back to white
    # (with a warning per side: see test_real_files_warn_only_where_the_draft_is_odd).
    "3parallelwarps": (3, 3, 3, 3, [GREEN_102, GREEN_102, WHITE], [WHITE] * 3),
    "41753": (48, 48, 10, 10, [BLUE] * 48, [WHITE] * 48),
    "54235plain": (2, 2, 2, 2, [GREEN_102] * 2, [WHITE] * 2),
    "8452": (84, 100, 28, 47, [GREEN_101] * 84, [WHITE] * 100),
}


# ---------------------------------------------------------------------------------------------
# Independent reference: configparser + loops, straight from the definitions
# ---------------------------------------------------------------------------------------------

def reference_drawdown(path: Path) -> np.ndarray:
    cp = configparser.ConfigParser(interpolation=None)
    cp.read(path, encoding="latin-1")
    ints = lambda s: [int(x) for x in s.split(",") if x.strip()]  # noqa: E731
    n_warp = cp.getint("WARP", "Threads")
    n_weft = cp.getint("WEFT", "Threads")
    rising = cp.getboolean("WEAVING", "Rising Shed", fallback=True)
    threading = {int(k): ints(v) for k, v in cp["THREADING"].items()}
    if cp.has_section("LIFTPLAN"):
        lifts = {int(k): set(ints(v)) for k, v in cp["LIFTPLAN"].items()}
    else:
        tieup = {int(k): ints(v) for k, v in cp["TIEUP"].items()}
        lifts = {}
        for k, v in cp["TREADLING"].items():
            shafts = set()
            for treadle in ints(v):
                shafts.update(tieup.get(treadle, []))
            lifts[int(k)] = shafts
    n_shafts = cp.getint("WEAVING", "Shafts")
    out = np.zeros((n_weft, n_warp), dtype=bool)
    for pick in range(1, n_weft + 1):
        if pick not in lifts:
            continue
        raised = lifts[pick] if rising else set(range(1, n_shafts + 1)) - lifts[pick]
        for end in range(1, n_warp + 1):
            out[pick - 1, end - 1] = any(s in raised for s in threading.get(end, []))
    return out


# ---------------------------------------------------------------------------------------------
# Real files
# ---------------------------------------------------------------------------------------------

@needs_data
@pytest.mark.parametrize("stem", sorted(REAL))
def test_real_file_counts_colours_meta(stem):
    n_warp, n_weft, shafts, treadles, warp_c, weft_c = REAL[stem]
    d = read_wif(WIF_DIR / f"{stem}.wif")
    assert isinstance(d, Draft)
    assert d.name == stem
    assert d.drawdown.shape == (n_weft, n_warp)
    assert (d.n_warp, d.n_weft) == (n_warp, n_weft)
    np.testing.assert_allclose(d.warp_colors, warp_c, atol=1e-12)
    np.testing.assert_allclose(d.weft_colors, weft_c, atol=1e-12)
    # Every file: Units=Centimeters, Spacing=0.0185, Thickness=0.0213.
    np.testing.assert_allclose(d.warp_spacing, 0.185)
    np.testing.assert_allclose(d.weft_spacing, 0.185)
    np.testing.assert_allclose(d.warp_thickness, 0.213)
    np.testing.assert_allclose(d.weft_thickness, 0.213)
    m = d.meta
    assert m["file"] == f"{stem}.wif"
    assert m["version"] == "1.2"
    assert m["source_program"] == "Handweaving.net Draft Library"
    assert (m["shafts"], m["treadles"], m["rising_shed"]) == (shafts, treadles, True)
    assert m["lift_source"] == "treadling"


@needs_data
@pytest.mark.parametrize("stem", sorted(REAL))
def test_real_file_drawdown_matches_reference(stem):
    path = WIF_DIR / f"{stem}.wif"
    np.testing.assert_array_equal(read_wif(path).drawdown, reference_drawdown(path))


@needs_data
def test_real_small_drawdowns_by_hand():
    # 54235plain: tieup 1->2, 2->1; threading 1->1, 2->2; treadling 1, 2.
    np.testing.assert_array_equal(read_wif(WIF_DIR / "54235plain.wif").drawdown, [[F, T], [T, F]])
    # 3parallelwarps: every end on shaft 1; treadles 1, 2, 1 lift shafts 1, 2, 1.
    np.testing.assert_array_equal(read_wif(WIF_DIR / "3parallelwarps.wif").drawdown,
                                  [[T, T, T], [F, F, F], [T, T, T]])
    # 2229 first pick: treadle 1 lifts shaft 3, i.e. ends 4, 8, 12, ... (threading 1,2,2,3 repeat).
    dd = read_wif(WIF_DIR / "2229.wif").drawdown
    assert [j + 1 for j in np.flatnonzero(dd[0])] == [4, 8, 12, 16, 20, 24]


@needs_data
@pytest.mark.parametrize("stem", sorted(REAL))
def test_real_file_every_truncation_is_draft_or_pattern_error(stem):
    """Cutting a real file at any byte must give a Draft or a PatternError naming the file."""
    data = (WIF_DIR / f"{stem}.wif").read_bytes()
    step = max(1, len(data) // 600)
    for cut in range(0, len(data), step):
        try:
            parse_wif(data[:cut], name="cut.wif")
        except PatternError as exc:
            assert str(exc).startswith("cut.wif: "), str(exc)


@needs_data
def test_real_file_random_corruption_is_draft_or_pattern_error():
    rng = random.Random(1234)
    junk = b"=,;[]x0-9 \r\n\xff\xe9"
    data = (WIF_DIR / "41753.wif").read_bytes()
    for _ in range(400):
        b = bytearray(data)
        for _ in range(rng.randint(1, 4)):
            b[rng.randrange(len(b))] = rng.choice(junk)
        try:
            parse_wif(bytes(b), name="bad.wif")
        except PatternError as exc:
            assert str(exc).startswith("bad.wif: "), str(exc)


# ---------------------------------------------------------------------------------------------
# Small drafts with known drawdowns
# ---------------------------------------------------------------------------------------------

def wif(weaving: str, threading: str, *, tieup: str | None = None, treadling: str | None = None,
        liftplan: str | None = None, warp: str = "", weft: str = "", extra: str = "") -> str:
    """A minimal WIF with the given section bodies (one 'key=value' per line)."""
    parts = ["[WIF]\nVersion=1.1\nDate=April 20, 1997\nDevelopers=test\nSource Program=test-suite\n",
             f"[WEAVING]\n{weaving}\n"]
    if warp:
        parts.append(f"[WARP]\n{warp}\n")
    if weft:
        parts.append(f"[WEFT]\n{weft}\n")
    parts.append(f"[THREADING]\n{threading}\n")
    if tieup is not None:
        parts.append(f"[TIEUP]\n{tieup}\n")
    if treadling is not None:
        parts.append(f"[TREADLING]\n{treadling}\n")
    if liftplan is not None:
        parts.append(f"[LIFTPLAN]\n{liftplan}\n")
    parts.append(extra)
    return "".join(parts)


PLAIN = wif("Shafts=2\nTreadles=2\nRising Shed=yes", "1=1\n2=2",
            tieup="1=1\n2=2", treadling="1=1\n2=2", warp="Threads=2", weft="Threads=2")

TWILL = wif("Shafts=4\nTreadles=4\nRising Shed=true", "1=1\n2=2\n3=3\n4=4",
            tieup="1=1,2\n2=2,3\n3=3,4\n4=4,1", treadling="1=1\n2=2\n3=3\n4=4",
            warp="Threads=4", weft="Threads=4")
# Pick i lifts shafts i and i+1 (mod 4); straight draw puts end j on shaft j.
TWILL_DD = [[T, T, F, F],
            [F, T, T, F],
            [F, F, T, T],
            [T, F, F, T]]
TWILL_LIFTPLAN = wif("Shafts=4\nRising Shed=1", "1=1\n2=2\n3=3\n4=4",
                     liftplan="1=1,2\n2=2,3\n3=3,4\n4=1,4", warp="Threads=4", weft="Threads=4")


def test_plain_weave():
    # Pick 1 presses treadle 1 -> shaft 1 up -> end 1 (on shaft 1) over the weft.
    d = parse_wif(PLAIN, name="plain.wif")
    np.testing.assert_array_equal(d.drawdown, [[T, F], [F, T]])
    assert d.name == "plain"
    assert d.meta["version"] == "1.1"


def test_twill_treadling_and_liftplan_agree():
    np.testing.assert_array_equal(parse_wif(TWILL).drawdown, TWILL_DD)
    d = parse_wif(TWILL_LIFTPLAN)
    np.testing.assert_array_equal(d.drawdown, TWILL_DD)
    assert d.meta["lift_source"] == "liftplan"


def test_sinking_shed_inverts():
    sinking = TWILL.replace("Rising Shed=true", "Rising Shed=no")
    np.testing.assert_array_equal(parse_wif(sinking).drawdown, ~np.array(TWILL_DD))
    assert parse_wif(sinking).meta["rising_shed"] is False
    sinking_lp = TWILL_LIFTPLAN.replace("Rising Shed=1", "Rising Shed=FALSE")
    np.testing.assert_array_equal(parse_wif(sinking_lp).drawdown, ~np.array(TWILL_DD))


def test_multiple_shafts_per_thread_and_treadles_per_pick():
    text = wif("Shafts=3\nTreadles=3", "1=1,2\n2=2\n3=3", tieup="1=1\n2=2\n3=3",
               treadling="1=1\n2=2\n3=3\n4=1,3", warp="Threads=3", weft="Threads=4")
    np.testing.assert_array_equal(parse_wif(text).drawdown,
                                  [[T, F, F],    # shaft 1: end 1 only
                                   [T, T, F],    # shaft 2: ends 1 (on 1 and 2) and 2
                                   [F, F, T],    # shaft 3: end 3
                                   [T, F, T]])   # treadles 1+3: shafts 1 and 3


def test_unthreaded_ends_and_unlisted_picks_lift_nothing():
    text = wif("Shafts=2\nTreadles=2", "1=1\n2=2", tieup="1=1\n2=2", treadling="1=1\n2=2",
               warp="Threads=3", weft="Threads=3")
    expected = [[T, F, F], [F, T, F], [F, F, F]]
    np.testing.assert_array_equal(parse_wif(text).drawdown, expected)
    # Sinking shed inverts the shafts of listed picks only; end 3 and pick 3 still lift nothing.
    sinking = text.replace("Treadles=2", "Treadles=2\nRising Shed=no")
    np.testing.assert_array_equal(parse_wif(sinking).drawdown, [[F, T, F], [T, F, F], [F, F, F]])


def test_counts_inferred_without_threads_keys():
    text = wif("Shafts=4\nTreadles=4", "1=1\n2=2\n3=3\n4=4",
               tieup="1=1,2\n2=2,3\n3=3,4\n4=4,1", treadling="1=1\n2=2\n3=3\n4=4\n5=1\n6=2")
    d = parse_wif(text)
    assert d.drawdown.shape == (6, 4)
    np.testing.assert_array_equal(d.drawdown[4:], np.array(TWILL_DD)[:2])
    np.testing.assert_allclose(d.warp_spacing, DEFAULT_SPACING_MM)


def test_zero_based_files_equal_one_based():
    one = parse_wif(TWILL).drawdown
    # Thread and pick keys counted from 0, shafts and treadles from 1 (the common variant).
    keys0 = wif("Shafts=4\nTreadles=4\nRising Shed=true", "0=1\n1=2\n2=3\n3=4",
                tieup="1=1,2\n2=2,3\n3=3,4\n4=4,1", treadling="0=1\n1=2\n2=3\n3=4",
                warp="Threads=4", weft="Threads=4")
    np.testing.assert_array_equal(parse_wif(keys0).drawdown, one)
    # Everything counted from 0.
    all0 = wif("Shafts=4\nTreadles=4", "0=0\n1=1\n2=2\n3=3",
               tieup="0=0,1\n1=1,2\n2=2,3\n3=3,0", treadling="0=0\n1=1\n2=2\n3=3",
               warp="Threads=4", weft="Threads=4")
    np.testing.assert_array_equal(parse_wif(all0).drawdown, one)
    lp0 = wif("Shafts=4", "0=0\n1=1\n2=2\n3=3", liftplan="0=0,1\n1=1,2\n2=2,3\n3=0,3",
              warp="Threads=4", weft="Threads=4")
    np.testing.assert_array_equal(parse_wif(lp0).drawdown, one)
    # The base is decided per section: 0-based THREADING with 1-based TREADLING (a rotation of
    # only one of them would shear the twill, so this catches a wrong base in either).
    mixed = TWILL.replace("[THREADING]\n1=1\n2=2\n3=3\n4=4", "[THREADING]\n0=1\n1=2\n2=3\n3=4")
    np.testing.assert_array_equal(parse_wif(mixed).drawdown, one)
    # An asymmetric draft (no cyclic symmetry to hide an off-by-one) and 0-based colours.
    asym1 = wif("Shafts=3\nTreadles=3", "1=1,2\n2=2\n3=3", tieup="1=1\n2=2\n3=3",
                treadling="1=1\n2=2\n3=3\n4=1,3", warp="Threads=3", weft="Threads=4",
                extra="[COLOR TABLE]\n1=255,0,0\n2=0,0,255\n[WARP COLORS]\n1=1\n2=2\n3=2\n")
    asym0 = wif("Shafts=3\nTreadles=3", "0=1,2\n1=2\n2=3", tieup="1=1\n2=2\n3=3",
                treadling="0=1\n1=2\n2=3\n3=1,3", warp="Threads=3", weft="Threads=4",
                extra="[COLOR TABLE]\n1=255,0,0\n2=0,0,255\n[WARP COLORS]\n0=1\n1=2\n2=2\n")
    _same_draft(parse_wif(asym0), parse_wif(asym1))
    np.testing.assert_allclose(parse_wif(asym0).warp_colors, [[1, 0, 0], [0, 0, 1], [0, 0, 1]])


COLOURED = TWILL + ("[COLOR PALETTE]\nEntries=3\nForm=RGB\nRange=0,255\n"
                    "[COLOR TABLE]\n1=255,0,0\n2=0,0,255\n3=0,255,0\n"
                    "[WARP COLORS]\n1=1\n2=2\n3=1\n4=2\n[WEFT COLORS]\n1=3\n2=3\n3=3\n4=3\n"
                    "[TEXT]\nTitle=Twill\n")


def _messy(text: str) -> str:
    """Same content: lower-case names, spaces around '=', comments, blank lines."""
    out = ["; written by a hypothetical program", ""]
    for line in text.splitlines():
        if line.startswith("["):
            out += ["", "  ;[4]Section comment, PixeLoom style", line.lower().replace(" ", "  ")]
        elif "=" in line:
            k, v = line.split("=", 1)
            out.append(f"  {k.lower()}  =  {v.replace(',', ' , ')}   ; inline comment")
    return "\n".join(out) + "\n"


def _same_draft(a: Draft, b: Draft):
    np.testing.assert_array_equal(a.drawdown, b.drawdown)
    for attr in ("warp_colors", "weft_colors", "warp_spacing", "weft_spacing",
                 "warp_thickness", "weft_thickness"):
        np.testing.assert_array_equal(getattr(a, attr), getattr(b, attr))


def test_comments_crlf_bom_case_latin1_parse_identically():
    base = parse_wif(COLOURED)
    np.testing.assert_array_equal(base.drawdown, TWILL_DD)
    np.testing.assert_allclose(base.warp_colors, [[1, 0, 0], [0, 0, 1], [1, 0, 0], [0, 0, 1]])
    np.testing.assert_allclose(base.weft_colors, [[0, 1, 0]] * 4)
    messy = _messy(COLOURED)
    assert "; inline comment" in messy and "[color  palette]" in messy
    variants = {
        "messy": messy,
        "crlf": COLOURED.replace("\n", "\r\n"),
        "cr": COLOURED.replace("\n", "\r"),
        "bom-bytes": b"\xef\xbb\xbf" + COLOURED.replace("\n", "\r\n").encode(),
        "bom-str": "\ufeff" + COLOURED,
        "latin1": COLOURED.replace("Title=Twill", "Title=Tw\xe9ed \xe0 carreaux").encode("latin-1"),
        "utf8": COLOURED.replace("Title=Twill", "Title=Tw\xe9ed").encode("utf-8"),
        "upper": COLOURED.upper(),
    }
    for label, text in variants.items():
        _same_draft(parse_wif(text, name=f"{label}.wif"), base)
    assert parse_wif(variants["latin1"]).meta["title"] == "Tw\xe9ed \xe0 carreaux"
    assert parse_wif(variants["utf8"]).meta["title"] == "Tw\xe9ed"


def test_colour_ranges_normalise():
    def colours(rng: str, entry: str) -> np.ndarray:
        text = PLAIN + f"[COLOR PALETTE]\nRange={rng}\n[COLOR TABLE]\n1={entry}\n[WARP]\nColor=1\n"
        return parse_wif(text).warp_colors[0]
    np.testing.assert_allclose(colours("0,65535", "65535,32768,0"), [1.0, 32768 / 65535, 0.0])
    np.testing.assert_allclose(colours("0,999", "999,0,333"), [1.0, 0.0, 333 / 999])   # Fiberworks
    np.testing.assert_allclose(colours("10,20", "10,15,20"), [0.0, 0.5, 1.0])


def test_default_colour_from_warp_color_key_and_no_colour_is_white():
    text = PLAIN.replace("[WARP]\nThreads=2", "[WARP]\nThreads=2\nColor=2") + (
        "[COLOR PALETTE]\nRange=0,255\n[COLOR TABLE]\n1=255,0,0\n2=0,0,255\n[WARP COLORS]\n2=1\n")
    d = parse_wif(text)
    np.testing.assert_allclose(d.warp_colors, [[0, 0, 1], [1, 0, 0]])    # default 2, end 2 -> 1
    np.testing.assert_allclose(d.weft_colors, [WHITE, WHITE])
    np.testing.assert_allclose(parse_wif(PLAIN).warp_colors, [WHITE, WHITE])


def test_units_and_per_thread_overrides():
    text = PLAIN.replace("[WARP]\nThreads=2", "[WARP]\nThreads=2\nUnits=Decipoints\nSpacing=20\nThickness=10")
    text = text.replace("[WEFT]\nThreads=2", "[WEFT]\nThreads=2\nUnits=inches\nSpacing=0.1")
    text += "[WARP SPACING]\n2=40\n[WEFT THICKNESS]\n1=0.01\n"
    d = parse_wif(text)
    dp = 25.4 / 720
    np.testing.assert_allclose(d.warp_spacing, [20 * dp, 40 * dp])
    np.testing.assert_allclose(d.warp_thickness, [10 * dp, 10 * dp])
    np.testing.assert_allclose(d.weft_spacing, [2.54, 2.54])
    np.testing.assert_allclose(d.weft_thickness, [0.254, 0.4])    # unset pick keeps the default
    assert d.meta["warp_units"] == "Decipoints"
    mm = parse_wif(PLAIN.replace("[WARP]\nThreads=2", "[WARP]\nThreads=2\nUnits=Millimeters\nSpacing=0.7"))
    np.testing.assert_allclose(mm.warp_spacing, [0.7, 0.7])
    cm = parse_wif(PLAIN.replace("[WARP]\nThreads=2", "[WARP]\nThreads=2\nUnits=Centimeters\nSpacing=0.05"))
    np.testing.assert_allclose(cm.warp_spacing, [0.5, 0.5])


def test_version_1_2_contents_and_optional_sections():
    text = PLAIN.replace("Version=1.1", "Version=1.2") + "[CONTENTS]\nWARP COLORS=yes\nNOTES=yes\n"
    d = parse_wif(text)     # listed but absent optional sections are only warnings
    assert d.meta["version"] == "1.2"
    assert any("WARP COLORS" in w for w in d.meta["warnings"])


def test_duplicate_key_with_same_value_is_fine():
    text = PLAIN.replace("[THREADING]\n1=1\n", "[THREADING]\n1=1\n1 = 1\n")
    np.testing.assert_array_equal(parse_wif(text).drawdown, [[T, F], [F, T]])


def test_read_wif_from_path(tmp_path):
    p = tmp_path / "my draft.wif"
    p.write_bytes(COLOURED.replace("\n", "\r\n").encode())
    d = read_wif(p)
    assert d.name == "my draft"
    assert d.meta["file"] == "my draft.wif"
    np.testing.assert_array_equal(d.drawdown, TWILL_DD)


# ---------------------------------------------------------------------------------------------
# Malformed files
# ---------------------------------------------------------------------------------------------

def line_of(text: str, section: str, line: str) -> int:
    """1-based line number of ``line`` inside ``[section]`` of ``text``."""
    lines = text.splitlines()
    start = lines.index(f"[{section}]")
    return start + 1 + lines[start:].index(line)


def expect_error(text, name: str, *fragments: str) -> str:
    with pytest.raises(PatternError) as info:
        parse_wif(text, name=name)
    msg = str(info.value)
    assert msg.startswith(f"{name}: "), msg
    for frag in fragments:
        assert frag in msg, f"{frag!r} not in {msg!r}"
    return msg


@needs_data
def test_truncated_real_file(tmp_path):
    lines = (WIF_DIR / "2229.wif").read_text().splitlines()
    assert lines[56] == "12=3" and lines[44] == "[THREADING]"      # line 57 of the file
    p = tmp_path / "2229.wif"
    for cut_line in ("12", "12="):
        p.write_text("\n".join(lines[:56] + [cut_line]))
        with pytest.raises(PatternError) as info:
            read_wif(p)
        msg = str(info.value)
        assert msg.startswith("2229.wif: [THREADING] line 57: "), msg
        assert "truncated" in msg
    p.write_text("\n".join(lines[:44]) + "\n")          # cut just before [THREADING]
    with pytest.raises(PatternError, match=r"^2229\.wif: \[THREADING\] missing.*\[CONTENTS\] line 14"):
        read_wif(p)
    p.write_text("\n".join(lines[:45]) + "\n")          # header only
    with pytest.raises(PatternError, match=r"^2229\.wif: \[THREADING\] line 45: section is empty"):
        read_wif(p)
    # Cut inside [TREADLING] (or right after it), which [CONTENTS] lists, as it lists the
    # colour sections that never come: read as it is, picks 3.. would float and the warp
    # turn white.
    assert lines[69] == "[TREADLING]" and lines[14] == "WARP COLORS=yes" and lines[94] == "[WARP COLORS]"
    for cut in (72, 94):
        p.write_text("\n".join(lines[:cut]) + "\n")
        with pytest.raises(PatternError, match=rf"^2229\.wif: \[TREADLING\] line {cut}: the file ends here, "
                                               r"but \[CONTENTS\] line 15 lists \[WARP COLORS\].*truncated"):
            read_wif(p)


def test_truncated_inline_cut_mid_colour():
    text = COLOURED.split("2=0,0,255")[0] + "2=0,0"
    expect_error(text, "cut.wif", "[COLOR TABLE] line", "3 numbers")


def test_unknown_shaft():
    text = TWILL.replace("[THREADING]\n1=1\n2=2\n3=3", "[THREADING]\n1=1\n2=2\n3=9")
    n = line_of(text, "THREADING", "3=9")
    expect_error(text, "s.wif", f"[THREADING] line {n}: shaft 9 does not exist (Shafts=4)")
    text = TWILL.replace("3=3,4\n4=4,1", "3=3,5\n4=4,1")
    n = line_of(text, "TIEUP", "3=3,5")
    expect_error(text, "s.wif", f"[TIEUP] line {n}: shaft 5 does not exist (Shafts=4)")
    text = TWILL_LIFTPLAN.replace("4=1,4", "4=1,7")
    n = line_of(text, "LIFTPLAN", "4=1,7")
    expect_error(text, "s.wif", f"[LIFTPLAN] line {n}: shaft 7 does not exist (Shafts=4)")


def test_unknown_treadle():
    text = TWILL.replace("[TREADLING]\n1=1\n2=2", "[TREADLING]\n1=1\n2=6")
    n = line_of(text, "TREADLING", "2=6")
    expect_error(text, "t.wif", f"[TREADLING] line {n}: treadle 6 does not exist (Treadles=4)")
    text = TWILL.replace("[TIEUP]\n1=1,2", "[TIEUP]\n5=1,2")
    n = line_of(text, "TIEUP", "5=1,2")
    expect_error(text, "t.wif", f"[TIEUP] line {n}: treadle 5 does not exist (Treadles=4)")


def test_missing_threading():
    text = PLAIN.replace("[THREADING]\n1=1\n2=2\n", "")
    assert "THREADING" not in text
    expect_error(text, "nothr.wif", "[THREADING] missing")
    listed = text.replace("[WEAVING]", "[CONTENTS]\nTHREADING=yes\n[WEAVING]")
    n = line_of(listed, "CONTENTS", "THREADING=yes")
    expect_error(listed, "nothr.wif", "[THREADING] missing", f"[CONTENTS] line {n}")


def test_neither_treadling_nor_liftplan():
    no_lift = PLAIN.replace("[TIEUP]\n1=1\n2=2\n", "").replace("[TREADLING]\n1=1\n2=2\n", "")
    expect_error(no_lift, "nolift.wif", "[LIFTPLAN] missing", "[TIEUP]+[TREADLING] or [LIFTPLAN]")
    no_tieup = PLAIN.replace("[TIEUP]\n1=1\n2=2\n", "")
    expect_error(no_tieup, "notieup.wif", "[TIEUP] missing")
    no_treadling = PLAIN.replace("[TREADLING]\n1=1\n2=2\n", "")
    expect_error(no_treadling, "notread.wif", "[TREADLING] missing")


@pytest.mark.parametrize("entry,expected", [
    ("1=0,101", "3 numbers"),                        # wrong component count
    ("1=0,abc,0", "'abc'"),                          # non-numeric
    ("1=0,300,0", "outside the palette Range 0,255"),  # out of range
])
def test_bad_colour_table_entry(entry, expected):
    text = COLOURED.replace("1=255,0,0", entry)
    n = line_of(text, "COLOR TABLE", entry)
    expect_error(text, "c.wif", f"[COLOR TABLE] line {n}: ", expected)


def test_colour_index_not_in_table():
    text = COLOURED.replace("[WARP COLORS]\n1=1\n2=2", "[WARP COLORS]\n1=1\n2=7")
    n = line_of(text, "WARP COLORS", "2=7")
    expect_error(text, "c.wif", f"[WARP COLORS] line {n}: colour 7 is not in [COLOR TABLE]")
    no_table = PLAIN + "[WEFT COLORS]\n1=1\n"
    n = line_of(no_table, "WEFT COLORS", "1=1")
    expect_error(no_table, "c.wif", f"[WEFT COLORS] line {n}: ", "no [COLOR TABLE]")


def test_bad_palette():
    text = COLOURED.replace("Range=0,255", "Range=255")
    expect_error(text, "p.wif", f"[COLOR PALETTE] line {line_of(text, 'COLOR PALETTE', 'Range=255')}: ")
    text = COLOURED.replace("Range=0,255", "Range=255,0")
    expect_error(text, "p.wif", "[COLOR PALETTE] line", "hi > lo")
    text = COLOURED.replace("Form=RGB", "Form=CMYK")
    expect_error(text, "p.wif", "[COLOR PALETTE] line", "Form=RGB")


@pytest.mark.parametrize("old,new,section,bad_line,fragment", [
    ("[THREADING]\n1=1", "[THREADING]\n1=x", "THREADING", "1=x", "'x'"),
    ("[THREADING]\n1=1", "[THREADING]\n1=1.5", "THREADING", "1=1.5", "'1.5'"),
    ("[THREADING]\n1=1", "[THREADING]\n1=1,,2", "THREADING", "1=1,,2", "an empty item"),
    ("[THREADING]\n1=1", "[THREADING]\nfirst=1", "THREADING", "first=1", "'first'"),
    ("[TREADLING]\n1=1", "[TREADLING]\n1=one", "TREADLING", "1=one", "'one'"),
    ("Shafts=2", "Shafts=four", "WEAVING", "Shafts=four", "'four'"),
    ("Shafts=2", "Shafts=0", "WEAVING", "Shafts=0", ">= 1"),
    ("Rising Shed=yes", "Rising Shed=maybe", "WEAVING", "Rising Shed=maybe", "'maybe'"),
    ("[WARP]\nThreads=2", "[WARP]\nThreads=-2", "WARP", "Threads=-2", "'-2'"),
    ("[WARP]\nThreads=2", "[WARP]\nThreads=2\nUnits=furlongs\nSpacing=1", "WARP", "Units=furlongs",
     "'furlongs'"),
    ("[WARP]\nThreads=2", "[WARP]\nThreads=2\nSpacing=wide", "WARP", "Spacing=wide", "'wide'"),
    ("[WARP]\nThreads=2", "[WARP]\nThreads=2\nThickness=0", "WARP", "Thickness=0", "> 0"),
    ("[WARP]\nThreads=2", "[WARP]\nThreads=1", "THREADING", "2=2",
     "warp end 2 does not exist ([WARP] Threads=1)"),
])
def test_non_numeric_and_invalid_values(old, new, section, bad_line, fragment):
    assert old in PLAIN
    text = PLAIN.replace(old, new, 1)
    n = line_of(text, section, bad_line)
    expect_error(text, "v.wif", f"[{section}] line {n}: ", fragment)


def test_line_without_equals_mid_file():
    text = TWILL.replace("[TIEUP]\n1=1,2", "[TIEUP]\n1 1,2")
    expect_error(text, "eq.wif", f"[TIEUP] line {line_of(text, 'TIEUP', '1 1,2')}: expected key=value")


def test_no_wif_section():
    expect_error(PLAIN.replace("[WIF]", "[WHATEVER]"), "x.wif", "not a WIF file", "[WIF]")
    expect_error("hello, world\n", "x.wif", "not a WIF file", "[WIF]")
    expect_error(b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR", "x.png", "not a WIF file")
    expect_error("", "empty.wif", "not a WIF file")
    # [WIF] but nothing useful.
    expect_error("[WIF]\nVersion=1.1\n", "x.wif", "[THREADING] missing")


def test_duplicate_conflicting_key():
    text = PLAIN.replace("[THREADING]\n1=1\n2=2", "[THREADING]\n1=1\n2=2\n1=2")
    lines = text.splitlines()
    first = line_of(text, "THREADING", "1=1")
    second = len(lines) - lines[::-1].index("1=2")
    assert second > first
    expect_error(text, "dup.wif", f"[THREADING] line {second}: duplicate key '1'", f"line {first}")
    # Key spelled differently (case, zero padding) is still the same key.
    text = PLAIN.replace("Shafts=2", "Shafts=2\nSHAFTS=3")
    expect_error(text, "dup.wif", f"[WEAVING] line {line_of(text, 'WEAVING', 'SHAFTS=3')}: duplicate key")
    text = PLAIN.replace("[THREADING]\n1=1", "[THREADING]\n1=1\n01=2")
    expect_error(text, "dup.wif", "[THREADING] line", "duplicate key '01'")


def test_zero_based_shafts_still_checked():
    text = wif("Shafts=4", "0=0\n1=1\n2=2\n3=4", liftplan="0=0,1", warp="Threads=4", weft="Threads=1")
    expect_error(text, "z.wif", f"[THREADING] line {line_of(text, 'THREADING', '3=4')}: shaft 4 does not exist",
                 "numbered from 0")


def test_file_not_found_and_directory(tmp_path):
    with pytest.raises(PatternError, match=r"^nope\.wif: cannot read WIF file"):
        read_wif(tmp_path / "nope.wif")
    d = tmp_path / "dir.wif"
    d.mkdir()
    with pytest.raises(PatternError, match=r"^dir\.wif: cannot read WIF file"):
        read_wif(d)


def test_errors_are_pattern_errors_not_bare_value_errors():
    # PatternError subclasses ValueError; make sure no plain ValueError/KeyError/IndexError leaks
    # from int()/dict lookups for a spread of broken inputs.
    broken = [
        PLAIN.replace("1=1\n2=2\n[TIEUP]", "1=\n2=2\n[TIEUP]"),
        PLAIN + "[WARP COLORS]\n1=\n",
        PLAIN + "[COLOR TABLE]\n1=1,2,3\nx=1,2,3\n",
        PLAIN + "[WARP SPACING]\n9=1\n",
        PLAIN + "[WEFT THICKNESS]\n1=-1\n",
        PLAIN.replace("Range", "") + "[COLOR PALETTE]\nRange=a,b\n",
        PLAIN + "[THREADING\n",
        PLAIN.replace("Treadles=2", "Treadles=x"),
        "[WIF]\n[THREADING]\n1=1\n[LIFTPLAN]\n",
    ]
    for text in broken:
        try:
            parse_wif(text, name="b.wif")
        except PatternError as exc:
            assert type(exc) is PatternError and str(exc).startswith("b.wif: ")


def test_empty_values_mid_file_mean_nothing():
    # Some writers leave "end=" for an unthreaded end; only at the file's end is it truncation.
    text = PLAIN.replace("[THREADING]\n1=1\n2=2", "[THREADING]\n1=1\n2=")
    np.testing.assert_array_equal(parse_wif(text).drawdown, [[T, F], [F, F]])


def test_liftplan_used_when_both_present():
    text = TWILL + "[LIFTPLAN]\n1=1\n2=1\n3=1\n4=1\n"
    d = parse_wif(text)
    assert d.meta["lift_source"] == "liftplan"
    np.testing.assert_array_equal(d.drawdown, [[T, F, F, F]] * 4)


def random_draft(rng: random.Random, liftplan: bool, rising: bool) -> tuple[str, np.ndarray]:
    """A random small draft (shafts on several ends, several treadles per pick, repeated and
    absent numbers, empty lines, untidy spacing) and its drawdown by nested loops."""
    n_shafts, n_treadles = rng.randint(1, 6), rng.randint(1, 5)
    n_warp, n_weft = rng.randint(1, 9), rng.randint(1, 9)

    def numbers(top: int) -> list[int]:
        return rng.choices(range(1, top + 1), k=rng.choice([0, 1, 1, 2, 3, 5]))   # k=0: empty line

    def lines(rows: dict[int, list[int]]) -> str:
        sep = lambda: rng.choice([",", ", ", " ,", "\t,\t"])  # noqa: E731
        return "\n".join(f"{k}={sep().join(map(str, v))}" for k, v in rows.items())

    threading = {j: numbers(n_shafts) for j in range(1, n_warp + 1) if rng.random() < 0.9}
    threading.setdefault(1, [1])                        # an empty [THREADING] is an error
    if liftplan:
        lifts = {i: numbers(n_shafts) for i in range(1, n_weft + 1) if rng.random() < 0.9}
        lifts.setdefault(1, [])
        sections = dict(liftplan=lines(lifts))
    else:
        tieup = {t: numbers(n_shafts) for t in range(1, n_treadles + 1) if rng.random() < 0.8}
        treadling = {i: numbers(n_treadles) for i in range(1, n_weft + 1) if rng.random() < 0.9}
        treadling.setdefault(1, [])
        lifts = {i: {s for t in ts for s in tieup.get(t, [])} for i, ts in treadling.items()}
        sections = dict(tieup=lines(tieup), treadling=lines(treadling))
    text = wif(f"Shafts={n_shafts}\nTreadles={n_treadles}\nRising Shed={'yes' if rising else 'no'}",
               lines(threading), warp=f"Threads={n_warp}", weft=f"Threads={n_weft}",
               extra="[TEXT]\nTitle=random\n", **sections)       # an empty last line means truncation
    expected = np.zeros((n_weft, n_warp), dtype=bool)
    for i in lifts:                                     # unlisted picks lift nothing
        raised = set(lifts[i]) if rising else set(range(1, n_shafts + 1)) - set(lifts[i])
        for j in range(1, n_warp + 1):
            expected[i - 1, j - 1] = any(s in raised for s in threading.get(j, []))
    return text, expected


@pytest.mark.parametrize("liftplan", [True, False], ids=["liftplan", "tieup"])
@pytest.mark.parametrize("rising", [True, False], ids=["rising", "sinking"])
def test_drawdown_matches_nested_loops_on_random_drafts(liftplan, rising):
    """The drawdown's matrix products (float32 BLAS) against the definition, thread by thread."""
    rng = random.Random(f"{liftplan}-{rising}")
    for _ in range(150):
        text, expected = random_draft(rng, liftplan, rising)
        d = parse_wif(text, name="r.wif")
        assert d.meta["lift_source"] == ("liftplan" if liftplan else "treadling")
        np.testing.assert_array_equal(d.drawdown, expected, err_msg=text)


def test_large_draft_reads_exactly():
    """2048 ends x 2048 picks on 1024 shafts (a jacquard-sized draft): the drawdown by the
    float32 product is exact. (Its speed, 15 s -> 0.4 s, is a measurement: performance log
    L70, not asserted here.)"""
    n, shafts = 2048, 1024
    join = ",".join
    text = wif(f"Shafts={shafts}\nTreadles={shafts}",
               "\n".join(f"{j + 1}={j % shafts + 1}" for j in range(n)),
               tieup="\n".join(f"{t + 1}=" + join(str((t + k) % shafts + 1) for k in range(shafts // 2))
                               for t in range(shafts)),
               treadling="\n".join(f"{i + 1}={i % shafts + 1}" for i in range(n)),
               warp=f"Threads={n}", weft=f"Threads={n}")
    d = parse_wif(text, name="big.wif")
    assert d.drawdown.shape == (n, n)
    # A 512/512 twill: pick i lifts shafts i..i+511 (mod 1024), end j is on shaft j (mod 1024).
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    np.testing.assert_array_equal(d.drawdown, (j - i) % shafts < shafts // 2)


def test_implausible_counts_refused():
    text = PLAIN.replace("[WARP]\nThreads=2", "[WARP]\nThreads=99999999")
    expect_error(text, "big.wif", f"[WARP] line {line_of(text, 'WARP', 'Threads=99999999')}: ",
                 "beyond the supported")
    text = PLAIN.replace("[WEFT]\nThreads=2\n", "").replace("[TREADLING]\n1=1", "[TREADLING]\n123456789=1")
    expect_error(text, "big.wif", "[TREADLING] line", "beyond the supported")


def test_thread_limit_is_what_maps_can_hold():
    """A draft with more threads than a largest (8192-texel) tile has room for, at the maps'
    least texels per thread, is refused when read, naming file, section, line and limit."""
    from mscloth.maps import woven
    from mscloth.maps.generator_support import MAX_RESOLUTION
    from mscloth.patterns.wif import MAX_THREADS

    assert MAX_THREADS == 4096
    assert MAX_THREADS * woven.MIN_TEXELS_PER_THREAD == MAX_RESOLUTION == 8192
    text = PLAIN.replace("[WARP]\nThreads=2", "[WARP]\nThreads=4097")
    expect_error(text, "wide.wif", f"wide.wif: [WARP] line {line_of(text, 'WARP', 'Threads=4097')}: "
                                   f"4097 threads is beyond the supported 4096")
    # Without Threads=, the count is the highest thread number used: refused at that line.
    text = PLAIN.replace("[WARP]\nThreads=2\n", "").replace("[THREADING]\n1=1", "[THREADING]\n4097=1")
    expect_error(text, "wide.wif", f"wide.wif: [THREADING] line {line_of(text, 'THREADING', '4097=1')}: "
                                   f"4097 warp ends is beyond the supported 4096")
    text = PLAIN.replace("[WEFT]\nThreads=2\n", "").replace("[TREADLING]\n1=1", "[TREADLING]\n4097=1")
    expect_error(text, "tall.wif", f"tall.wif: [TREADLING] line {line_of(text, 'TREADLING', '4097=1')}: "
                                   f"4097 weft picks is beyond the supported 4096")
    # The limit itself is fine.
    d = parse_wif(PLAIN.replace("[WARP]\nThreads=2", "[WARP]\nThreads=4096"))
    assert d.drawdown.shape == (2, 4096)


@needs_data
def test_thread_colour_without_colour_table_warns_once_and_weaves(tmp_path):
    """[WARP]/[WEFT] Color= names a palette colour, but there is no [COLOR TABLE] (nor colour
    sections): weaving programs open such files, and so do we, with white and one warning."""
    lines = (WIF_DIR / "2229.wif").read_text().splitlines()
    dropped = ("COLOR TABLE=", "WARP COLORS=", "WEFT COLORS=")
    kept, section = [], None
    for line in lines:
        if line.startswith("["):
            section = line
        if section in ("[COLOR TABLE]", "[WARP COLORS]", "[WEFT COLORS]") or line.startswith(dropped):
            continue
        kept.append(line)
        if line == "Threads=24":
            kept.append("Color=1")          # in [WARP] and in [WEFT]
    p = tmp_path / "nocolours.wif"
    p.write_text("\n".join(kept) + "\n")
    with pytest.warns(UserWarning) as caught:
        d = read_wif(p)
    assert len(caught) == 1
    message = str(caught[0].message)
    assert message.startswith("nocolours.wif: [WARP] line ") and "[WEFT] line" in message
    assert "no [COLOR TABLE]" in message
    np.testing.assert_array_equal(d.drawdown, reference_drawdown(WIF_DIR / "2229.wif"))
    assert d.warp_colors is None or np.allclose(d.warp_colors, 1.0)
    assert d.weft_colors is None or np.allclose(d.weft_colors, 1.0)
    # With a table, a colour it lacks is still an error.
    with_table = "\n".join(kept).replace("[WARP]", "[COLOR TABLE]\n1=0,101,0\n[WARP]").replace("Color=1", "Color=3")
    expect_error(with_table, "t.wif", "[WARP] line", "colour 3 is not in [COLOR TABLE]")


# ---------------------------------------------------------------------------------------------
# Warnings: every guess and every odd draft is shown, once per read, naming file and section
# ---------------------------------------------------------------------------------------------

# PLAIN with spacings in millimetres: reads without any warning.
SPACED = PLAIN.replace("[WARP]\nThreads=2", "[WARP]\nThreads=2\nUnits=Millimeters\nSpacing=0.5") \
              .replace("[WEFT]\nThreads=2", "[WEFT]\nThreads=2\nUnits=Millimeters\nSpacing=0.5")


def wif_warnings(read, *args, **kwargs) -> list[str]:
    """The messages of every warning ``read(*args, **kwargs)`` emits (all shown)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        read(*args, **kwargs)
    return [str(w.message) for w in caught]


def test_clean_draft_does_not_warn():
    assert wif_warnings(parse_wif, SPACED, name="t.wif") == []
    assert parse_wif(SPACED).meta["warnings"] == []


def no_units_2229(tmp_path) -> Path:
    """2229.wif without its Units= lines (``sed '/^Units=/d'``): Centimeters read as decipoints."""
    text = (WIF_DIR / "2229.wif").read_text()
    p = tmp_path / "nounits.wif"
    p.write_text("".join(line for line in text.splitlines(keepends=True) if not line.startswith("Units=")))
    return p


@needs_data
def test_missing_units_warns_with_the_tile_it_gives(tmp_path):
    p = no_units_2229(tmp_path)
    line = p.read_text().splitlines().index("Spacing=0.0185") + 1      # the [WARP] one
    with pytest.warns(UserWarning, match=re.escape(
            f"nounits.wif: [WARP] has no Units= for Spacing=0.0185 (line {line}); assuming decipoints "
            f"(tile 0.0157 mm wide): give Units=")) as caught:
        d = read_wif(p)
    assert any(str(w.message).startswith("nounits.wif: [WEFT] has no Units= for Spacing=0.0185")
               and "(tile 0.0157 mm tall)" in str(w.message) for w in caught)
    assert len(caught) == 2
    np.testing.assert_allclose(d.size_mm, 24 * 0.0185 * 25.4 / 720)     # 0.0157 mm, not 4.44 mm
    assert d.meta["warp_units"] == "Decipoints"
    assert len(d.meta["warnings"]) == 2 and d.meta["warnings"][0].startswith("[WARP] has no Units=")


def test_missing_units_with_thickness_only_warns():
    text = SPACED.replace("Units=Millimeters\nSpacing=0.5", "Thickness=10", 1)
    with pytest.warns(UserWarning, match=re.escape(
            "t.wif: [WARP] has no Units= for Thickness=10 (line ")) as caught:
        parse_wif(text, name="t.wif")
    assert any("assuming decipoints (yarns 0.353 mm thick)" in str(w.message) for w in caught)


def test_missing_spacing_warns():
    text = SPACED.replace("Units=Millimeters\nSpacing=0.5", "", 1)           # [WARP] only
    with pytest.warns(UserWarning, match=re.escape(
            "t.wif: [WARP] has no Spacing=; assuming 0.5 mm between warp ends (tile 1 mm wide): "
            "give Spacing= and Units=")) as caught:
        d = parse_wif(text, name="t.wif")
    assert len(caught) == 1
    np.testing.assert_allclose(d.warp_spacing, DEFAULT_SPACING_MM)


def test_partial_spacing_section_warns():
    text = SPACED.replace("Units=Millimeters\nSpacing=0.5", "Units=Millimeters", 1) \
        + "[WARP SPACING]\n1=0.7\n"
    with pytest.warns(UserWarning, match=re.escape(
            "t.wif: [WARP SPACING] gives no spacing for 1 of 2 warp ends and [WARP] has no Spacing=; "
            "assuming 0.5 mm for them (tile 1.2 mm wide)")):
        d = parse_wif(text, name="t.wif")
    np.testing.assert_allclose(d.warp_spacing, [0.7, 0.5])


# SPACED with a colour table: [WARP COLORS] / [WEFT COLORS] bodies are appended per test.
PALETTE = SPACED + "[COLOR PALETTE]\nRange=0,255\n[COLOR TABLE]\n1=255,0,0\n2=0,0,255\n"


def test_thread_colours_missing_from_colour_section_warn_once_per_section():
    text = PALETTE.replace("Threads=2", "Threads=3", 1).replace("[THREADING]\n1=1\n2=2",
                                                                 "[THREADING]\n1=1\n2=2\n3=1")
    partial = text + "[WARP COLORS]\n1=2\n[WEFT COLORS]\n2=1\n"
    assert wif_warnings(parse_wif, partial, name="c.wif") == [
        "c.wif: [WARP COLORS] gives no colour for 2 of 3 warp ends (first: end 2); white used",
        "c.wif: [WEFT COLORS] gives no colour for 1 of 2 weft picks (first: pick 1); white used"]
    d = parse_wif(partial)
    np.testing.assert_allclose(d.warp_colors, [[0, 0, 1], WHITE, WHITE])
    np.testing.assert_allclose(d.weft_colors, [WHITE, [1, 0, 0]])
    assert d.meta["warnings"][-1].startswith("[WEFT COLORS] gives no colour for 1 of 2")
    # An empty value gives no colour either; numbering from 0 is kept in the message.
    empty0 = text + "[WARP COLORS]\n0=1\n1=\n2=2\n[WEFT COLORS]\n1=1\n2=1\n"
    assert wif_warnings(parse_wif, empty0, name="c.wif") == [
        "c.wif: [WARP COLORS] gives no colour for 1 of 3 warp ends (first: end 1); white used"]
    # Every thread listed, or a default Color= for the rest, or no colour section: no guess.
    full = text + "[WARP COLORS]\n1=1\n2=1\n3=2\n[WEFT COLORS]\n1=1\n2=1\n"
    assert wif_warnings(parse_wif, full, name="c.wif") == []
    defaulted = partial.replace("[WARP]\n", "[WARP]\nColor=1\n").replace("[WEFT]\n", "[WEFT]\nColor=2\n")
    assert wif_warnings(parse_wif, defaulted, name="c.wif") == []
    np.testing.assert_allclose(parse_wif(defaulted).warp_colors, [[0, 0, 1], [1, 0, 0], [1, 0, 0]])
    assert wif_warnings(parse_wif, text, name="c.wif") == []


def test_palette_range_16_bit_with_8_bit_colours_warns():
    text = PALETTE.replace("Range=0,255", "Range=0,65535") + "[WARP COLORS]\n1=1\n2=2\n"
    assert wif_warnings(parse_wif, text, name="p.wif") == [
        "p.wif: [COLOR PALETTE] Range=0,65535 but every colour is <= 255: the cloth will be nearly "
        "black; was Range=0,255 meant?"]
    d = parse_wif(text)                 # read as the file says, all the same
    np.testing.assert_allclose(d.warp_colors, [[255 / 65535, 0, 0], [0, 0, 255 / 65535]])
    assert d.meta["warnings"] == [
        "[COLOR PALETTE] Range=0,65535 but every colour is <= 255: the cloth will be nearly black; "
        "was Range=0,255 meant?"]
    # 16-bit values, an all-black table, or an 8-bit Range: nothing to say.
    for quiet in (text.replace("1=255,0,0", "1=65535,0,0"),
                  text.replace("1=255,0,0", "1=0,0,0").replace("2=0,0,255", "2=0,0,0"),
                  text.replace("Range=0,65535", "Range=0,255")):
        assert wif_warnings(parse_wif, quiet, name="p.wif") == []


def test_text_before_first_section_warns_once():
    text = "Saved by LoomProgram 2.0\nexport of 2024-01-01\n" + SPACED
    with pytest.warns(UserWarning, match=re.escape(
            "t.wif: line 1: text before the first section ignored ('Saved by LoomProgram 2.0' "
            "and 1 more line)")) as caught:
        d = parse_wif(text, name="t.wif")
    assert len(caught) == 1
    np.testing.assert_array_equal(d.drawdown, [[T, F], [F, T]])


def test_missing_shafts_warns():
    text = SPACED.replace("Shafts=2\n", "")
    with pytest.warns(UserWarning, match=r"^t\.wif: \[WEAVING\] has no Shafts=; Shafts=2 inferred from the "
                                         r"highest shaft used \(\[THREADING\] line \d+\): give Shafts=$"):
        d = parse_wif(text, name="t.wif")
    assert d.meta["shafts"] == 2


def test_unthreaded_warp_ends_warn():
    text = SPACED.replace("Threads=2", "Threads=6", 1).replace("[THREADING]\n1=1\n2=2", "[THREADING]\n1=1\n2=\n6=2")
    with pytest.warns(UserWarning, match=re.escape(
            "t.wif: [THREADING] gives no shaft for warp ends 2-5 (of 6): never lifted, they float under "
            "every pick across the whole tile")):
        d = parse_wif(text, name="t.wif")
    assert not d.drawdown[:, 1:5].any()
    one = SPACED.replace("Threads=2", "Threads=3", 1)
    with pytest.warns(UserWarning, match=re.escape("[THREADING] gives no shaft for warp end 3 (of 3): "
                                                   "never lifted, it floats")):
        parse_wif(one, name="t.wif")


def test_unlisted_weft_picks_warn():
    text = SPACED.replace("[WEFT]\nThreads=2", "[WEFT]\nThreads=4")
    with pytest.warns(UserWarning, match=re.escape(
            "t.wif: [TREADLING] has no entry for weft picks 3-4 (of 4): nothing is lifted, so they float "
            "over every warp end across the whole tile")):
        parse_wif(text, name="t.wif")


@pytest.mark.parametrize("tieup, expected", [
    # Every treadle lifts nothing (empty tie-up lines): the weft covers the warp.
    ("1=\n2=", "[TIEUP]: no thread interlaces: the treadles of every pick lift none of the shafts the "
               "warp is threaded on, so the tile is every pick over the warp, with no weave"),
    # Every treadle lifts every shaft: the warp covers the weft.
    ("1=1,2\n2=1,2", "[TIEUP]: no thread interlaces: the treadles of every pick lift all of the shafts"),
    # Nothing, then everything: each pick lies wholly over or under the warp.
    ("1=\n2=1,2", "[TIEUP]: no weft pick interlaces with the warp: the treadles of every pick lift none "
                  "or all of the shafts the warp is threaded on"),
])
def test_tieup_that_never_interlaces_warns(tieup, expected):
    text = SPACED.replace("[TIEUP]\n1=1\n2=2", f"[TIEUP]\n{tieup}")
    with pytest.warns(UserWarning, match=re.escape(f"t.wif: {expected}")) as caught:
        parse_wif(text, name="t.wif")
    assert len(caught) == 1


def test_liftplan_lifting_the_same_shafts_every_pick_warns():
    text = SPACED.replace("[TIEUP]\n1=1\n2=2\n[TREADLING]\n1=1\n2=2", "[LIFTPLAN]\n1=1\n2=1")
    with pytest.warns(UserWarning, match=re.escape(
            "t.wif: [LIFTPLAN]: no warp end interlaces with the weft: every pick lifts the same shafts, "
            "so each warp end lies over or under every pick across the whole tile")):
        parse_wif(text, name="t.wif")


def test_earlier_warnings_are_shown_too():
    """Warnings the reader only recorded in meta before are shown as well."""
    listed = SPACED.replace("Version=1.1", "Version=1.2") + "[CONTENTS]\nWARP COLORS=yes\n"
    with pytest.warns(UserWarning, match=re.escape("t.wif: [CONTENTS] line ")):
        parse_wif(listed, name="t.wif")
    with pytest.warns(UserWarning, match=re.escape("t.wif: no [COLOR PALETTE] Range: 0,255 assumed")):
        parse_wif(SPACED + "[COLOR TABLE]\n1=255,0,0\n", name="t.wif")


def test_each_warning_once_per_read_with_its_category_and_callers_line(tmp_path):
    from mscloth import patterns
    from mscloth.patterns.wif import WifWarning

    p = tmp_path / "odd.wif"
    p.write_text("junk\n" + SPACED.replace("Shafts=2\n", "").replace("Threads=2", "Threads=3", 1))
    for read in (read_wif, patterns.read_wif, patterns.named_pattern):
        for _ in range(2):                      # a second read warns again, once
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                read(str(p))
            messages = [str(w.message) for w in caught]
            assert len(messages) == 3 and len(set(messages)) == 3, messages
            assert all(m.startswith("odd.wif: ") for m in messages)
            assert all(w.category is WifWarning and issubclass(w.category, UserWarning) for w in caught)
            # Attributed to the caller outside mscloth (here), not to the reader's internals.
            assert {w.filename for w in caught} == {__file__}, [w.filename for w in caught]
    assert len(read_wif(p).meta["warnings"]) == 3


@needs_data
def test_maps_keep_the_warnings_and_cached_maps_do_not_repeat_them(tmp_path):
    from mscloth.maps.builtin import clear_cache, resolve_pattern
    from mscloth.maps.cloth_maps import ClothMaps

    p = no_units_2229(tmp_path)
    clear_cache()
    with pytest.warns(UserWarning, match="nounits.wif: \\[WARP\\] has no Units="):
        maps = resolve_pattern(str(p), 48)
    assert [w[:34] for w in maps.meta["warnings"]] == ["nounits.wif: [WARP] has no Units= ",
                                                       "nounits.wif: [WEFT] has no Units= "]
    # The same file at the same resolution comes from the cache: not read, so not warned again
    # (its maps still carry the warnings, and maps.json keeps them).
    assert wif_warnings(resolve_pattern, str(p), 48) == []
    assert resolve_pattern(str(p), 48) is maps
    maps.save(tmp_path / "out")
    assert ClothMaps.load(tmp_path / "out").meta["warnings"] == maps.meta["warnings"]
    clear_cache()


@needs_data
def test_real_files_warn_only_where_the_draft_is_odd():
    """The shared handweaving.net files give Units, Spacing, Shafts and a full threading: only
    3parallelwarps warns, as it should: its three ends all sit on shaft 1, which every pick
    lifts or leaves down, so each pick lies over or under the whole warp; and its colour
    sections stop at thread 2 of 3, with no default Color=, so thread 3 is white by a guess."""
    found = {stem: wif_warnings(read_wif, WIF_DIR / f"{stem}.wif") for stem in sorted(REAL)}
    assert found.pop("3parallelwarps") == [
        "3parallelwarps.wif: [TIEUP]: no weft pick interlaces with the warp: the treadles of every pick "
        "lift none or all of the shafts the warp is threaded on, so each pick lies over or under every "
        "warp end across the whole tile",
        "3parallelwarps.wif: [WARP COLORS] gives no colour for 1 of 3 warp ends (first: end 3); white used",
        "3parallelwarps.wif: [WEFT COLORS] gives no colour for 1 of 3 weft picks (first: pick 3); white used"]
    assert found == {stem: [] for stem in found}
