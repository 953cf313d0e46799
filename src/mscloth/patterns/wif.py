"""Read weave drafts from WIF (Weaving Information File, spec 1.1) files.

WIF is the INI-like interchange format that handweaving programs (Fiberworks, PixeLoom,
WeaveIt, handweaving.net, ...) export. What matters for cloth appearance is the drawdown,
which a WIF does not store: it is computed here from the loom set-up the file records,

    threading  (warp end  -> shaft(s) it passes through),
    tieup      (treadle   -> shafts it lifts)  + treadling (pick -> treadle(s) pressed), or
    liftplan   (pick      -> shafts lifted),

as  ``lifted = treadling @ tieup`` (picks x shafts) and
``drawdown = lifted @ threading.T > 0`` (picks x ends): warp end j is on top at pick i iff
any shaft that end passes through is raised at pick i.

Reading is tolerant of what real files contain (case-insensitive names, ``;`` comments,
CRLF, a BOM, latin-1 text, 0-based thread numbers, missing optional sections) and strict
about anything that would change the cloth: every malformed value raises
:class:`~mscloth.errors.PatternError` naming the file, the section, the 1-based line and
what was expected, e.g. ``2229.wif: [THREADING] line 57: shaft 9 does not exist (Shafts=8)``.

Conventions chosen where the spec is silent. When one was needed, or the draft weaves oddly
(warp ends without a shaft, picks without an entry, no thread interlacing), a
:class:`WifWarning` (a UserWarning) says so, once per read, as one line naming the file and,
where known, the section and line, e.g. ``nounits.wif: [WARP] has no Units= for Spacing=0.0185
(line 32); assuming decipoints (tile 0.0157 mm wide): give Units= ...``. The messages are
also kept in ``Draft.meta["warnings"]`` (without the file name) and in the maps'
``meta["warnings"]`` (with it), so ``maps.json`` records them.

* Numbering is 1-based as the spec says. A thread section (THREADING, WARP COLORS, ...)
  containing key 0 is read as 0-based. Shaft numbers are read as 0-based only if shaft 0
  occurs somewhere (THREADING/TIEUP/LIFTPLAN values); treadle numbers likewise (TIEUP keys,
  TREADLING values). Colour indices are looked up as written, so any base works.
* Ends missing from THREADING are unthreaded: never lifted, weft on top. Picks missing from
  TREADLING/LIFTPLAN lift nothing, whatever the shed type. A listed pick with an empty
  value selects no shaft (which in a sinking shed means every shaft stays up).
* ``Rising Shed=no`` (sinking shed): the tieup/liftplan names the shafts that sink, so the
  raised shafts are the others.
* When both LIFTPLAN and TIEUP+TREADLING are present, LIFTPLAN is used (it is the lift
  sequence itself; the two agree in files written by consistent programs).
* An empty value is tolerated (means "nothing"), except on the last line of the file, where
  it is taken as a number cut off by truncation.
* ``Units`` missing while a spacing/thickness is given: decipoints are assumed.
  ``Spacing`` missing: 0.5 mm (``DEFAULT_SPACING_MM``). ``Shafts``/``Treadles`` missing:
  the highest one used. ``Range`` missing from COLOR PALETTE: ``0,255`` is assumed.
* Threads a WARP COLORS / WEFT COLORS section leaves out take the ``[WARP]``/``[WEFT]``
  ``Color=``, else white (with a warning). Colours are read in the palette's ``Range`` as
  given, even where ``Range=0,65535`` holds only 8-bit values (with a warning).
"""
from __future__ import annotations

import functools
import itertools
import math
import os
import re
import sys
import warnings
from dataclasses import dataclass, field
from pathlib import Path
import numpy as np

from ..errors import PatternError
from .draft import DEFAULT_SPACING_MM, DEFAULT_THICKNESS_MM, Draft

__all__ = ["read_wif", "parse_wif", "WifWarning", "UNIT_MM", "MAX_THREADS", "MAX_SHAFTS"]

#: Millimetres per WIF length unit. A decipoint is a tenth of a printer's point (1/72 in).
UNIT_MM = {
    "DECIPOINTS": 25.4 / 720.0,
    "INCHES": 25.4,
    "CENTIMETERS": 10.0,
    "MILLIMETERS": 1.0,
}
# Spellings seen in the wild (singular, British, abbreviations) -> the canonical unit.
_UNIT_ALIASES = {
    "DECIPOINT": "DECIPOINTS", "DECIPOINTS": "DECIPOINTS", "DP": "DECIPOINTS",
    "INCH": "INCHES", "INCHES": "INCHES", "IN": "INCHES",
    "CENTIMETER": "CENTIMETERS", "CENTIMETERS": "CENTIMETERS", "CENTIMETRE": "CENTIMETERS",
    "CENTIMETRES": "CENTIMETERS", "CM": "CENTIMETERS",
    "MILLIMETER": "MILLIMETERS", "MILLIMETERS": "MILLIMETERS", "MILLIMETRE": "MILLIMETERS",
    "MILLIMETRES": "MILLIMETERS", "MM": "MILLIMETERS",
}
_BOOLS = {"YES": True, "TRUE": True, "ON": True, "1": True,
          "NO": False, "FALSE": False, "OFF": False, "0": False}

# Sections whose syntax is checked up front (in file order), so the first malformed line of
# anything the draft is built from is reported, wherever the reading code would meet it.
# Unknown sections ([TEXT], [NOTES], program-private ones) are never checked: a stray line
# there cannot change the cloth.
_CHECKED_SECTIONS = (
    "WIF", "CONTENTS", "WEAVING", "WARP", "WEFT", "COLOR PALETTE", "COLOR TABLE",
    "THREADING", "TIEUP", "TREADLING", "LIFTPLAN", "WARP COLORS", "WEFT COLORS",
    "WARP SPACING", "WEFT SPACING", "WARP THICKNESS", "WEFT THICKNESS",
)

#: Sanity limits: beyond any loom (jacquards have a few thousand hooks), small enough that a
#: garbage count cannot make the drawdown allocate gigabytes. MAX_THREADS is the most ends or
#: picks that can still become maps: those need at least ``maps.woven.MIN_TEXELS_PER_THREAD``
#: (2) texels per thread in a tile of at most 8192 texels a side
#: (``maps.generator_support.MAX_RESOLUTION``), so 8192 // 2. (The value is
#: written out, not imported: patterns must not depend on maps; tests/test_wif.py checks the
#: relation.)
MAX_THREADS = 4096
MAX_SHAFTS = 4096

_INT_RE = re.compile(r"[+]?\d+\Z")
_NUM_RE = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?\Z")
_DECIMAL_COMMA_RE = re.compile(r"[+-]?\d+,\d+\Z")
_INT_LIST_RE = re.compile(r"[ \t]*\+?[0-9]+[ \t]*(?:,[ \t]*\+?[0-9]+[ \t]*)*\Z")


def _norm(name: str) -> str:
    """Canonical spelling of a section or key name: upper case, single spaces, US 'COLOR'."""
    out = " ".join(name.split()).upper().replace("COLOUR", "COLOR")
    # '01' and '1' are the same thread: compare numeric keys by value.
    return str(int(out)) if _INT_RE.match(out) else out


@dataclass
class _Entry:
    key: str        # as written (for messages)
    value: str      # comment and surrounding whitespace stripped
    line: int       # 1-based line in the file


@dataclass
class _Section:
    name: str                                   # canonical, e.g. "WARP COLORS"
    line: int                                   # line of the (first) header
    entries: dict[str, _Entry] = field(default_factory=dict)
    problems: list[tuple[int, str]] = field(default_factory=list)   # (line, message)


class _Wif:
    """A WIF file split into sections, with helpers that raise well-placed PatternErrors."""

    def __init__(self, text: str, fname: str):
        self.fname = fname
        self.sections: dict[str, _Section] = {}
        self.order: list[str] = []
        self.last_line = 0          # last line carrying data: where truncation shows
        self.last_section: str | None = None   # the section that line is in
        self.colourless: list[str] = []         # "[WARP] line 31" of Color=index without a [COLOR TABLE]
        self.warnings: list[str] = []
        self._split(text)

    # -- errors -------------------------------------------------------------------------
    def error(self, section: str | None, line: int | None, msg: str) -> PatternError:
        where = self.fname
        if section is not None:
            where += f": [{section}]"
        if line is not None:
            where += f" line {line}"
        return PatternError(f"{where}: {msg}")

    # -- lexing ---------------------------------------------------------------------------
    def _split(self, text: str) -> None:
        # Split on CRLF / CR / LF only: str.splitlines() also splits on form feeds, vertical
        # tabs and U+2028, which would make line numbers disagree with a text editor's.
        current: _Section | None = None
        preamble: list[tuple[int, str]] = []      # (line, text) before the first header
        for lineno, raw in enumerate(re.split(r"\r\n|\r|\n", text), start=1):
            line = raw.split(";", 1)[0].strip()      # ';' starts a comment, whole-line or inline
            if not line:
                continue
            self.last_line = lineno
            if line.startswith("["):
                if line.endswith("]") and len(line) > 2:
                    name = _norm(line[1:-1])
                    if name not in self.sections:
                        self.sections[name] = _Section(name, lineno)
                        self.order.append(name)
                    current = self.sections[name]     # a repeated header continues the section
                    self.last_section = name
                    continue
                msg = f"expected a section header like [THREADING] or a key=value line, got {line!r}"
                if current is not None:
                    current.problems.append((lineno, msg))
                continue
            if current is None:
                # Text before the first header: harmless if the file turns out to be a WIF.
                preamble.append((lineno, line))
                continue
            key, eq, value = line.partition("=")
            key, value = key.strip(), value.strip()
            if not eq or not key:
                current.problems.append((lineno, f"expected key=value, got {line!r}"))
                continue
            nkey = _norm(key)
            old = current.entries.get(nkey)
            if old is None:
                current.entries[nkey] = _Entry(key, value, lineno)
            elif "".join(old.value.split()).upper() != "".join(value.split()).upper():
                current.problems.append(
                    (lineno, f"duplicate key {key!r}: {value!r} here but {old.value!r} on line {old.line}"))
        if preamble:
            (first, snippet), more = preamble[0], len(preamble) - 1
            snippet = snippet if len(snippet) <= 40 else snippet[:37] + "..."
            self.warnings.append(
                f"line {first}: text before the first section ignored ({snippet!r}"
                + (f" and {more} more line{'s' if more > 1 else ''})" if more else ")"))

    def check_syntax(self) -> None:
        """Raise for the first malformed line of any section the draft is built from."""
        found = [(line, name, msg) for name in self.order if name in _CHECKED_SECTIONS
                 for line, msg in self.sections[name].problems]
        if found:
            line, name, msg = min(found)
            if line == self.last_line:      # a broken last line is what truncation looks like
                msg += " (the file ends here: truncated?)"
            raise self.error(name, line, msg)

    # -- access ---------------------------------------------------------------------------
    def section(self, name: str) -> _Section | None:
        return self.sections.get(name)

    def get(self, section: str, key: str) -> _Entry | None:
        sec = self.sections.get(section)
        return None if sec is None else sec.entries.get(key)

    # -- value parsers (each raises naming section and line) --------------------------------
    def empty_ok(self, section: str, entry: _Entry, what: str) -> bool:
        """True if ``entry`` is empty and that is acceptable (anywhere but the file's end)."""
        if entry.value:
            return False
        if entry.line == self.last_line:
            raise self.error(section, entry.line,
                             f"expected {what} after '{entry.key}=', got nothing (the file ends here: truncated?)")
        return True

    def int_value(self, section: str, entry: _Entry, what: str, lo: int = 1) -> int:
        text = entry.value
        if not text:
            self.empty_ok(section, entry, what)
            raise self.error(section, entry.line, f"expected {what} after '{entry.key}=', got nothing")
        if not _INT_RE.match(text):
            raise self.error(section, entry.line, f"expected {what} (a whole number), got {text!r}")
        value = int(text)
        if value < lo:
            raise self.error(section, entry.line, f"expected {what} >= {lo}, got {value}")
        return value

    def int_list(self, section: str, entry: _Entry, what: str) -> list[int]:
        """Comma-separated non-negative integers; empty -> [] (see empty_ok)."""
        if self.empty_ok(section, entry, f"{what} numbers"):
            return []
        # Jacquard liftplans hold millions of numbers: check a well-formed line with one regex
        # (a strict subset of what the loop below accepts) and leave errors to the loop.
        if _INT_LIST_RE.match(entry.value):
            return list(map(int, entry.value.split(",")))
        out = []
        for item in entry.value.split(","):
            item = item.strip()
            if not _INT_RE.match(item):
                got = "an empty item" if not item else repr(item)
                raise self.error(section, entry.line,
                                 f"expected {what} numbers separated by commas, got {got} in {entry.value!r}")
            out.append(int(item))
        return out

    def float_value(self, section: str, entry: _Entry, what: str) -> float:
        text = entry.value
        if not text:
            self.empty_ok(section, entry, what)
            raise self.error(section, entry.line, f"expected {what} after '{entry.key}=', got nothing")
        if _DECIMAL_COMMA_RE.match(text):       # "0,0185" from a decimal-comma locale
            text = text.replace(",", ".")
        if not _NUM_RE.match(text):
            raise self.error(section, entry.line, f"expected {what} (a number), got {entry.value!r}")
        value = float(text)
        if not math.isfinite(value) or value <= 0.0:
            raise self.error(section, entry.line, f"expected {what} > 0, got {entry.value!r}")
        return value

    def bool_value(self, section: str, entry: _Entry) -> bool:
        value = _BOOLS.get(entry.value.upper())
        if value is None:
            raise self.error(section, entry.line,
                             f"expected yes/no/true/false/1/0 for {entry.key!r}, got {entry.value!r}")
        return value

    def key_number(self, section: str, entry: _Entry, what: str) -> int:
        if not _INT_RE.match(entry.key.strip()):
            raise self.error(section, entry.line, f"expected a {what} number as the key, got {entry.key!r}")
        return int(entry.key)


# ---------------------------------------------------------------------------------------
# Public API
# ---------------------------------------------------------------------------------------

def read_wif(path) -> Draft:
    """Read the WIF file at ``path`` into a :class:`Draft` named after the file's stem.

    Raises PatternError (never OSError / KeyError / ValueError) when the file cannot be
    read or is not a usable WIF; the message names the file, section and line.
    """
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise PatternError(f"{p.name}: cannot read WIF file {str(p)!r}: {reason}") from None
    return parse_wif(data, name=p.name)


def _numbering(wif, uses: list[_Uses], count, kind: str, key: str, default_section: str) -> tuple[int, int]:
    """(base, count) of one numbering (shafts or treadles) from its ``uses``, in file-reading
    order. Numbering starts at 0 if any use is 0, else at 1; a missing [WEAVING] count is
    inferred from the largest number used (with a warning); a number beyond the count is an
    error at its line (the first such use, as ``uses`` are ordered)."""
    zero = next(((u.section, u.entry(k)) for u in uses for k in np.flatnonzero(u.numbers == 0)[:1]), None)
    base = 0 if zero is not None else 1
    note = (f"; {kind}s are numbered from 0 here because [{zero[0]}] line "
            f"{zero[1].line} uses {kind} 0" if zero is not None else "")
    if count is None:
        sec, e, top = default_section, None, base
        used = [u for u in uses if u.numbers.size]
        if used:
            top = max(u.numbers.max() for u in used)
            u = next(u for u in used if u.numbers.max() == top)          # the first use of it
            sec, e = u.section, u.entry(np.flatnonzero(u.numbers == top)[0])
        count = int(top) - base + 1
        if e is not None:
            _capped(wif, sec, e, count, MAX_SHAFTS, f"{kind}s")
        where = f" ([{sec}] line {e.line})" if e is not None else ""
        wif.warnings.append(f"[WEAVING] has no {key}=; {key}={count} inferred from the highest "
                            f"{kind} used{where}: give {key}=")
    for u in uses:
        beyond = np.flatnonzero(u.numbers - base >= count)
        if beyond.size:
            n = u.numbers[beyond[0]]
            raise wif.error(u.section, u.entry(beyond[0]).line,
                            f"{kind} {n} does not exist ({key}={count}{note})")
    return base, count


def parse_wif(text: str | bytes, name: str = "<string>") -> Draft:
    """Parse WIF content (``str``, or ``bytes`` in any common encoding) into a Draft.

    ``name`` is the file name used in error messages; the Draft is named after its stem.
    """
    fname = Path(name).name or name
    wif = _Wif(_decode(text), fname)
    draft = _build(wif, name)
    _emit_warnings(fname, draft.meta["warnings"])
    return draft


class WifWarning(UserWarning):
    """A WIF file was read, but by a guess (a unit, a spacing, a count it does not give) or
    into a draft that weaves oddly (unthreaded ends, no interlacing): the message names the
    file and, where known, the section and line. Filter it with
    ``warnings.simplefilter("ignore", WifWarning)``."""


_PACKAGE_DIR = str(Path(__file__).resolve().parents[1])     # .../mscloth


def _emit_warnings(fname: str, messages: list[str]) -> None:
    """Show each of ``messages`` once, as a WifWarning ``"<file>: <message>"`` attributed to
    the first caller outside mscloth (the user's ``read_wif``, ``generate_maps`` or
    ``mi.load_dict`` call), whichever mscloth function read the file."""
    if not messages:
        return
    level, frame = 1, sys._getframe(0)
    while frame.f_back is not None and _in_package(frame.f_code.co_filename):
        frame, level = frame.f_back, level + 1
    for message in dict.fromkeys(messages):          # unique, in order
        warnings.warn(f"{fname}: {message}", WifWarning, stacklevel=level)


@functools.lru_cache(maxsize=256)
def _in_package(filename: str) -> bool:
    try:
        path = str(Path(filename).resolve())
    except (OSError, RuntimeError, ValueError):
        return False
    return path.startswith(_PACKAGE_DIR + os.sep)


def _decode(data: str | bytes) -> str:
    """Text of a WIF whatever program wrote it: BOMs removed, non-UTF-8 read as cp1252/latin-1."""
    if isinstance(data, str):
        return data.lstrip("\ufeff")
    if data.startswith(b"\xef\xbb\xbf"):
        return data[3:].decode("utf-8", errors="replace")
    if data.startswith((b"\xff\xfe", b"\xfe\xff")):
        return data.decode("utf-16", errors="replace")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        pass
    try:
        return data.decode("cp1252")           # Windows programs' usual 8-bit encoding
    except UnicodeDecodeError:
        return data.decode("latin-1")          # total: every byte is a character


# ---------------------------------------------------------------------------------------
# Building the draft
# ---------------------------------------------------------------------------------------

@dataclass
class _Numbered:
    """A thread-numbered section: 0-based index -> entry, plus the numbering base used."""
    section: str
    base: int
    items: dict[int, _Entry]


def _numbered(wif: _Wif, name: str, what: str) -> _Numbered | None:
    sec = wif.section(name)
    if sec is None:
        return None
    keyed = {wif.key_number(name, e, what): e for e in sec.entries.values()}
    # Key 0 only occurs in files that count from 0 (the spec counts from 1).
    base = 0 if 0 in keyed else 1
    return _Numbered(name, base, {k - base: e for k, e in keyed.items()})


def _limit_threads(wif: _Wif, num: _Numbered | None, count: int, explicit: bool, side: str) -> None:
    """Check thread numbers against the thread count; extras are an error if the count was stated
    ([WARP]/[WEFT] Threads), otherwise (count inferred from the threading/treadling) ignored."""
    if num is None:
        return
    kind = "warp end" if side == "WARP" else "weft pick"
    for idx in sorted(num.items):
        if idx >= count:
            e = num.items[idx]
            if explicit:
                raise wif.error(num.section, e.line,
                                f"{kind} {idx + num.base} does not exist ([{side}] Threads={count}"
                                + (", numbered from 0)" if num.base == 0 else ")"))
            wif.warnings.append(f"[{num.section}] line {e.line}: {kind} {idx + num.base} beyond the "
                                f"{count} {kind}s in the draft, ignored")
    num.items = {k: e for k, e in num.items.items() if k < count}


def _count(wif: _Wif, section: str) -> tuple[int | None, _Entry | None]:
    e = wif.get(section, "THREADS")
    if e is None:
        return None, None
    return _capped(wif, section, e, wif.int_value(section, e, "the number of threads"), MAX_THREADS, "threads"), e


def _capped(wif: _Wif, section: str, entry: _Entry, value: int, limit: int, what: str) -> int:
    if value > limit:
        raise wif.error(section, entry.line, f"{value} {what} is beyond the supported {limit}")
    return value


def _build(wif: _Wif, name: str) -> Draft:
    fname = wif.fname
    if "WIF" not in wif.sections:
        found = ", ".join(f"[{s}]" for s in wif.order[:6]) or "no sections at all"
        raise PatternError(f"{fname}: not a WIF file: no [WIF] section (found {found})")
    wif.check_syntax()
    meta: dict = {"file": fname, "format": "WIF"}
    for key, label in (("VERSION", "version"), ("SOURCE PROGRAM", "source_program"),
                       ("SOURCE VERSION", "source_version"), ("DATE", "date")):
        e = wif.get("WIF", key)
        if e is not None:
            meta[label] = e.value
    title = wif.get("TEXT", "TITLE")
    if title is not None and title.value:
        meta["title"] = title.value

    contents = wif.section("CONTENTS")

    def missing(section: str, need: str) -> PatternError:
        """Error for an absent required section, pointing at [CONTENTS] if it promised it."""
        msg = f"[{section}] missing: {need}"
        listed = contents.entries.get(section) if contents is not None else None
        if listed is not None and _BOOLS.get(listed.value.upper(), True):
            msg += f" ([CONTENTS] line {listed.line} lists it: is the file truncated?)"
        return PatternError(f"{fname}: {msg}")

    # Sections [CONTENTS] promises that the file lacks: (line in [CONTENTS], name).
    absent = [] if contents is None else [(e.line, key) for key, e in contents.entries.items()
                                          if _BOOLS.get(e.value.upper(), False) and key not in wif.sections]

    # --- loom: shafts, treadles, shed -------------------------------------------------------
    n_shafts = n_treadles = None
    rising = True
    e = wif.get("WEAVING", "SHAFTS")
    if e is not None:
        n_shafts = _capped(wif, "WEAVING", e, wif.int_value("WEAVING", e, "the number of shafts"),
                           MAX_SHAFTS, "shafts")
    e = wif.get("WEAVING", "TREADLES")
    if e is not None and e.value:      # liftplan-only files sometimes leave it empty / 0
        n_treadles = _capped(wif, "WEAVING", e, wif.int_value("WEAVING", e, "the number of treadles", lo=0),
                             MAX_SHAFTS, "treadles")
    e = wif.get("WEAVING", "RISING SHED")
    if e is not None:
        rising = wif.bool_value("WEAVING", e)

    # --- threading -----------------------------------------------------------------------------
    if wif.section("THREADING") is None:
        raise missing("THREADING", "a draft needs a threading (which shaft each warp end is on)")
    threading = _numbered(wif, "THREADING", "warp end")
    if not threading.items:
        raise wif.error("THREADING", wif.sections["THREADING"].line,
                        "section is empty: expected end=shaft lines (truncated file?)")
    thr_shafts = {i: wif.int_list("THREADING", e, "shaft") for i, e in threading.items.items()}

    n_warp, _ = _count(wif, "WARP")
    warp_explicit = n_warp is not None
    if n_warp is None:
        n_warp = max(threading.items) + 1
        _capped(wif, "THREADING", threading.items[n_warp - 1], n_warp, MAX_THREADS, "warp ends")
    _limit_threads(wif, threading, n_warp, warp_explicit, "WARP")
    thr_shafts = {i: s for i, s in thr_shafts.items() if i in threading.items}
    unthreaded = [i for i in range(n_warp) if not thr_shafts.get(i)]     # missing or empty
    _floating_warning(wif, unthreaded, threading.base, n_warp, "[THREADING] gives no shaft for", "warp end",
                      "never lifted, {they} under every pick across the whole tile; thread {them}")

    # --- lift sequence -------------------------------------------------------------------------
    has_lift = wif.section("LIFTPLAN") is not None
    has_tread = wif.section("TREADLING") is not None
    has_tieup = wif.section("TIEUP") is not None
    if has_lift:
        lift_source = "liftplan"
        picks = _numbered(wif, "LIFTPLAN", "weft pick")
        pick_values = {i: wif.int_list("LIFTPLAN", e, "shaft") for i, e in picks.items.items()}
        tieup_items: dict[int, list[int]] = {}
        tieup_num = None
    elif has_tread and has_tieup:
        lift_source = "treadling"
        picks = _numbered(wif, "TREADLING", "weft pick")
        pick_values = {i: wif.int_list("TREADLING", e, "treadle") for i, e in picks.items.items()}
        tieup_sec = wif.sections["TIEUP"]
        tieup_num = {wif.key_number("TIEUP", e, "treadle"): e for e in tieup_sec.entries.values()}
        tieup_items = {t: wif.int_list("TIEUP", e, "shaft") for t, e in tieup_num.items()}
    elif has_tread:
        raise missing("TIEUP", "[TREADLING] names treadles but there is no [TIEUP] saying which "
                               "shafts they lift (or give a [LIFTPLAN])")
    else:
        which = "[TIEUP] without [TREADLING]" if has_tieup else "neither"
        raise missing("TREADLING" if has_tieup else "LIFTPLAN",
                      f"a draft needs [TIEUP]+[TREADLING] or [LIFTPLAN] to say which shafts each "
                      f"pick lifts; found {which}")
    lift_name = picks.section
    if not picks.items:
        raise wif.error(lift_name, wif.sections[lift_name].line,
                        "section is empty: expected pick=... lines (truncated file?)")

    # A file that ends in a section [CONTENTS] lists, while sections it lists never come, was
    # cut off: read as it is, its last section would lose picks (or ends) and the missing
    # colours would turn white. (A writer that lists a section it does not write, with
    # [CONTENTS] or an unlisted section last, only gets a warning.)
    ending = wif.last_section
    if absent and ending is not None and ending != "CONTENTS" and ending in contents.entries \
            and _BOOLS.get(contents.entries[ending].value.upper(), False):
        line, key = absent[0]
        raise wif.error(ending, wif.last_line, f"the file ends here, but [CONTENTS] line {line} lists "
                                               f"[{key}], which never comes (the file is truncated?)")
    for line, key in absent:
        wif.warnings.append(f"[CONTENTS] line {line} lists [{key}] but the file has none")

    n_weft, _ = _count(wif, "WEFT")
    weft_explicit = n_weft is not None
    if n_weft is None:
        n_weft = max(picks.items) + 1
        _capped(wif, lift_name, picks.items[n_weft - 1], n_weft, MAX_THREADS, "weft picks")
    _limit_threads(wif, picks, n_weft, weft_explicit, "WEFT")
    pick_values = {i: v for i, v in pick_values.items() if i in picks.items}
    unlisted = [i for i in range(n_weft) if i not in picks.items]
    _floating_warning(wif, unlisted, picks.base, n_weft, f"[{lift_name}] has no entry for", "weft pick",
                      "nothing is lifted, so {they} over every warp end across the whole tile")

    # --- shaft numbering: one namespace across threading, tieup and liftplan ----------------
    thr_uses = _Uses.of("THREADING", thr_shafts, threading.items)
    if lift_source == "liftplan":
        lift_uses = _Uses.of("LIFTPLAN", pick_values, picks.items)
    else:
        lift_uses = _Uses.of("TIEUP", tieup_items, tieup_num)
    shaft_base, n_shafts = _numbering(wif, [thr_uses, lift_uses], n_shafts, "shaft", "Shafts", "THREADING")

    # --- treadle numbering (TIEUP keys, TREADLING values) ------------------------------------
    if lift_source == "treadling":
        tieup_keys = _Uses.of("TIEUP", {t: [t] for t in tieup_num}, tieup_num)
        tread_uses = _Uses.of("TREADLING", pick_values, picks.items)
        tread_base, n_treadles = _numbering(wif, [tieup_keys, tread_uses], n_treadles or None,
                                            "treadle", "Treadles", "TIEUP")

    # --- drawdown: boolean matrix products --------------------------------------------------
    thread_m = np.zeros((n_warp, n_shafts), dtype=bool)          # end -> shafts
    thr_uses.scatter(thread_m, shaft_base)
    if lift_source == "liftplan":
        selected = np.zeros((n_weft, n_shafts), dtype=bool)       # pick -> shafts
        lift_uses.scatter(selected, shaft_base)
    else:
        tieup_m = np.zeros((n_treadles, n_shafts), dtype=bool)    # treadle -> shafts
        lift_uses.scatter(tieup_m, shaft_base, row_base=tread_base)
        tread_m = np.zeros((n_weft, n_treadles), dtype=bool)      # pick -> treadles
        tread_uses.scatter(tread_m, tread_base)
        selected = _any_product(tread_m, tieup_m)
    # Sinking shed: the tieup/liftplan names the shafts pulled down; the rest are up.
    raised = selected if rising else ~selected
    listed = np.zeros(n_weft, dtype=bool)
    listed[list(picks.items)] = True
    raised &= listed[:, None]                                     # absent picks lift nothing
    drawdown = _any_product(raised, thread_m.T)
    interlacing = _interlacing_warning(drawdown, thread_m.any(axis=1), lift_source)
    if interlacing is not None:
        wif.warnings.append(interlacing)

    # --- colours ------------------------------------------------------------------------------
    table, rng = _color_table(wif)
    warp_colors = _thread_colors(wif, "WARP", n_warp, warp_explicit, table, rng)
    weft_colors = _thread_colors(wif, "WEFT", n_weft, weft_explicit, table, rng)
    if wif.colourless:
        # Weaving programs open such files (their palette is their own default): so do we.
        message = (f"{' and '.join(wif.colourless)}: Color= names a palette colour but there is no "
                   f"[COLOR TABLE]; white used")
        wif.warnings.append(message)

    # --- spacing / thickness ------------------------------------------------------------------
    warp_units, warp_factor, warp_assumed = _units(wif, "WARP")
    weft_units, weft_factor, weft_assumed = _units(wif, "WEFT")
    warp_spacing, warp_unspaced = _lengths(wif, "WARP", "SPACING", n_warp, warp_explicit, warp_factor,
                                           DEFAULT_SPACING_MM)
    weft_spacing, weft_unspaced = _lengths(wif, "WEFT", "SPACING", n_weft, weft_explicit, weft_factor,
                                           DEFAULT_SPACING_MM)
    warp_thick, warp_unthick = _lengths(wif, "WARP", "THICKNESS", n_warp, warp_explicit, warp_factor,
                                        DEFAULT_THICKNESS_MM)
    weft_thick, weft_unthick = _lengths(wif, "WEFT", "THICKNESS", n_weft, weft_explicit, weft_factor,
                                        DEFAULT_THICKNESS_MM)
    for side, assumed, count, spacing, unspaced, unthick in (
            ("WARP", warp_assumed, n_warp, warp_spacing, warp_unspaced, warp_unthick),
            ("WEFT", weft_assumed, n_weft, weft_spacing, weft_unspaced, weft_unthick)):
        _length_warnings(wif, side, assumed, count, spacing, unspaced, unthick)

    meta.update({
        "shafts": n_shafts,
        "treadles": n_treadles or 0,
        "rising_shed": rising,
        "lift_source": lift_source,
        "warp_units": warp_units,
        "weft_units": weft_units,
        "warnings": wif.warnings,
    })
    try:
        return Draft(drawdown, warp_colors=warp_colors, weft_colors=weft_colors,
                     warp_spacing=warp_spacing, weft_spacing=weft_spacing,
                     warp_thickness=warp_thick, weft_thickness=weft_thick,
                     name=Path(name).stem or name, meta=meta)
    except PatternError as exc:       # should not happen: values were checked above
        raise PatternError(f"{fname}: {exc}") from None


def _any_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Boolean matrix product: ``out[i, j] = any(a[i, :] & b[:, j])``.

    NumPy multiplies integer matrices without BLAS (~15 s for a 2048-end, 1024-shaft draft);
    float32 goes through BLAS and is exact here: every partial sum is a count of 0/1 products,
    at most the number of shafts or treadles (<= MAX_SHAFTS = 4096) < 2**24, which float32
    represents exactly, whatever the summation order.
    """
    return (a.astype(np.float32) @ b.astype(np.float32)) > 0


@dataclass
class _Uses:
    """The numbers one section uses (shafts, treadles), flattened so that checks and the
    matrix writes are array operations (a jacquard liftplan holds millions of them):
    ``numbers[k]`` is in row ``keys[owner[k]]``, written on line ``entries[owner[k]]``."""
    section: str
    keys: list[int]                 # row (thread or treadle) of each entry
    entries: list[_Entry]
    numbers: np.ndarray             # int64, or object where a number overflows int64
    owner: np.ndarray               # index into keys / entries of each number

    @classmethod
    def of(cls, section: str, values: dict[int, list[int]], entries: dict[int, _Entry]) -> "_Uses":
        keys = list(values)
        counts = np.fromiter(map(len, values.values()), dtype=np.int64, count=len(keys))
        flat = itertools.chain.from_iterable(values.values())
        try:
            numbers = np.fromiter(flat, dtype=np.int64, count=int(counts.sum()))
        except OverflowError:       # "shaft 99999999999999999999": still reported as written
            numbers = np.array(list(itertools.chain.from_iterable(values.values())), dtype=object)
        owner = np.repeat(np.arange(len(keys)), counts)
        return cls(section, keys, [entries[k] for k in keys], numbers, owner)

    def entry(self, k) -> _Entry:
        """The entry (line) that number ``k`` was written on."""
        return self.entries[self.owner[k]]

    def scatter(self, matrix: np.ndarray, base: int, row_base: int = 0) -> None:
        """Set ``matrix[row - row_base, number - base] = True`` for every use, in one write.
        Only once the numbers have been checked against the matrix (see _numbering)."""
        if self.numbers.size:
            rows = np.asarray(self.keys, dtype=np.int64)[self.owner] - row_base
            matrix[rows, self.numbers.astype(np.int64) - base] = True


def _color_table(wif: _Wif) -> tuple[dict[int, np.ndarray], tuple[float, float]]:
    """COLOR TABLE as index -> sRGB in [0, 1], normalised by the palette's Range."""
    lo, hi = 0.0, 255.0
    form = wif.get("COLOR PALETTE", "FORM")
    if form is not None and form.value and form.value.upper() != "RGB":
        raise wif.error("COLOR PALETTE", form.line, f"expected Form=RGB (the only WIF colour form), got {form.value!r}")
    rng = wif.get("COLOR PALETTE", "RANGE")
    if rng is not None:
        parts = [p.strip() for p in rng.value.split(",")]
        if len(parts) != 2 or not all(_NUM_RE.match(p) for p in parts):
            raise wif.error("COLOR PALETTE", rng.line, f"expected Range=lo,hi (two numbers), got {rng.value!r}")
        lo, hi = float(parts[0]), float(parts[1])
        if not hi > lo:
            raise wif.error("COLOR PALETTE", rng.line, f"expected Range=lo,hi with hi > lo, got {rng.value!r}")
    elif wif.section("COLOR TABLE") is not None:
        wif.warnings.append("no [COLOR PALETTE] Range: 0,255 assumed")
    table: dict[int, np.ndarray] = {}
    top = 0.0                       # the largest component as written
    sec = wif.section("COLOR TABLE")
    if sec is not None:
        for e in sec.entries.values():
            idx = wif.key_number("COLOR TABLE", e, "colour")
            table[idx] = _rgb(wif, "COLOR TABLE", e, e.value, (lo, hi))
            top = max(top, *(float(v) for v in e.value.split(",")))
    # 8-bit values under a 16-bit Range: valid, but every colour comes out below 0.4 %
    # (nearly black), which is what a writer that mislabels its Range produces. The values
    # are read as the file says; the warning lets the user see why.
    if hi > 255 and 0 < top <= 255:
        wif.warnings.append(f"[COLOR PALETTE] Range={lo:g},{hi:g} but every colour is <= 255: the cloth "
                            f"will be nearly black; was Range={lo:g},255 meant?")
    return table, (lo, hi)


def _rgb(wif: _Wif, section: str, entry: _Entry, text: str, rng: tuple[float, float]) -> np.ndarray:
    lo, hi = rng
    parts = [p.strip() for p in text.split(",")]
    if len(parts) != 3:
        raise wif.error(section, entry.line,
                        f"expected a colour r,g,b (3 numbers), got {len(parts)} value(s) in {text!r}")
    bad = [p for p in parts if not _NUM_RE.match(p)]
    if bad:
        raise wif.error(section, entry.line, f"expected colour components as numbers, got {bad[0]!r} in {text!r}")
    vals = np.array([float(p) for p in parts])
    if np.any(vals < lo) or np.any(vals > hi):
        raise wif.error(section, entry.line,
                        f"colour {text!r} is outside the palette Range {lo:g},{hi:g}")
    return (vals - lo) / (hi - lo)


def _thread_colors(wif: _Wif, side: str, count: int, explicit: bool,
                   table: dict[int, np.ndarray], rng) -> np.ndarray | None:
    """Per-thread colours: [SIDE COLORS] entry, else [SIDE] Color, else white (None)."""
    section = f"{side} COLORS"

    def lookup(sec: str, e: _Entry, index: int) -> np.ndarray:
        if index not in table:
            have = (f"it has {', '.join(map(str, sorted(table)[:8]))}"
                    + ("..." if len(table) > 8 else "")) if table else "there is no [COLOR TABLE]"
            raise wif.error(sec, e.line, f"colour {index} is not in [COLOR TABLE] ({have})")
        return table[index]

    default = None
    e = wif.get(side, "COLOR")
    has_default = e is not None and bool(e.value)
    if has_default:
        parts = [p.strip() for p in e.value.split(",")]
        if len(parts) == 1:
            index = wif.int_value(side, e, "a colour index", lo=0)
            if wif.section("COLOR TABLE") is None:
                wif.colourless.append(f"[{side}] line {e.line}")  # the default colour, with a warning
            else:
                default = lookup(side, e, index)
        elif len(parts) in (3, 4):
            # Some writers give "index,r,g,b" or just "r,g,b": the RGB is the colour itself.
            default = _rgb(wif, side, e, ",".join(parts[-3:]), rng)
        else:
            raise wif.error(side, e.line, f"expected Color=index (or index,r,g,b), got {e.value!r}")
    num = _numbered(wif, section, f"{side.lower()} thread")
    if num is None and default is None:
        return None
    colors = np.tile(np.ones(3) if default is None else default, (count, 1))
    _limit_threads(wif, num, count, explicit, side)
    if num is not None:
        given = np.zeros(count, dtype=bool)
        for i, e in num.items.items():
            if wif.empty_ok(section, e, "a colour index"):
                continue
            colors[i] = lookup(section, e, wif.int_value(section, e, "a colour index", lo=0))
            given[i] = True
        # Without a [SIDE] Color= the others' white is a guess (a writer that lists only some
        # threads, or a cut-off list); with one (even one without a [COLOR TABLE], which has
        # its own warning) the others take it, as the file says.
        if not has_default and not given.all():
            kind, short = ("warp end", "end") if side == "WARP" else ("weft pick", "pick")
            first = int(np.argmin(given)) + num.base
            wif.warnings.append(f"[{section}] gives no colour for {int(count - given.sum())} of {count} "
                                f"{kind}s (first: {short} {first}); white used")
    return colors


def _units(wif: _Wif, side: str) -> tuple[str | None, float, bool]:
    """(unit name, mm per unit, assumed) of one side's lengths: decipoints are assumed (with a
    warning, see _length_warnings) when lengths are given without Units; the name is None when
    none are given."""
    e = wif.get(side, "UNITS")
    if e is None or not e.value:
        uses = [wif.get(side, "SPACING"), wif.get(side, "THICKNESS"),
                wif.section(f"{side} SPACING"), wif.section(f"{side} THICKNESS")]
        if any(u is not None for u in uses):
            return "Decipoints", UNIT_MM["DECIPOINTS"], True
        return None, UNIT_MM["DECIPOINTS"], False   # no lengths given: nothing to convert
    unit = _UNIT_ALIASES.get(_norm(e.value))
    if unit is None:
        raise wif.error(side, e.line, f"expected Units=Decipoints, Inches, Centimeters or Millimeters, got {e.value!r}")
    return unit.title(), UNIT_MM[unit], False


def _lengths(wif: _Wif, side: str, what: str, count: int, explicit: bool,
             factor: float, default_mm: float) -> tuple[np.ndarray | None, int]:
    """Per-thread spacing or thickness in mm: [SIDE WHAT] entry, else [SIDE] What, else default;
    and how many threads got the default."""
    e = wif.get(side, what)
    base = None
    if e is not None and e.value:
        base = wif.float_value(side, e, f"a {what.lower()}") * factor
    num = _numbered(wif, f"{side} {what}", f"{side.lower()} thread")
    if num is None:
        return (None, count) if base is None else (np.full(count, base), 0)
    _limit_threads(wif, num, count, explicit, side)
    out = np.full(count, default_mm if base is None else base)
    given = np.zeros(count, dtype=bool)
    for i, ent in num.items.items():
        if wif.empty_ok(num.section, ent, f"a {what.lower()}"):
            continue
        out[i] = wif.float_value(num.section, ent, f"a {what.lower()}") * factor
        given[i] = True
    return out, 0 if base is not None else int(count - given.sum())


def _length_warnings(wif: _Wif, side: str, units_assumed: bool, count: int, spacing: np.ndarray | None,
                     unspaced: int, unthick: int) -> None:
    """Warn about one side's lengths that are guesses: no Units (decipoints assumed, which makes
    a file written in centimetres ~280 times too small) and spacings the file does not give."""
    kind = "warp end" if side == "WARP" else "weft pick"
    extent = "wide" if side == "WARP" else "tall"
    tile_mm = (DEFAULT_SPACING_MM * count if spacing is None else float(spacing.sum()))
    if units_assumed and (unspaced < count or unthick < count):   # a length was given, unitless
        e = next((e for e in (wif.get(side, "SPACING"), wif.get(side, "THICKNESS"))
                  if e is not None and e.value), None)
        if unspaced < count:
            size = f" (tile {tile_mm:.3g} mm {extent})"
        elif e is not None:           # only thicknesses were given: [SIDE] Thickness=
            size = f" (yarns {wif.float_value(side, e, 'a thickness') * UNIT_MM['DECIPOINTS']:.3g} mm thick)"
        else:                         # only a [SIDE THICKNESS] section
            size = ""
        sec = next((n for n in (f"{side} SPACING", f"{side} THICKNESS") if wif.section(n) is not None),
                   f"{side} SPACING")
        given = (f" for {e.key.strip()}={e.value} (line {e.line})" if e is not None
                 else f" for its [{sec}] (line {wif.sections[sec].line})" if sec in wif.sections else "")
        wif.warnings.append(f"[{side}] has no Units={given}; assuming decipoints{size}: give Units= "
                            f"(Decipoints, Inches, Centimeters or Millimeters)")
    if unspaced == count:
        wif.warnings.append(f"[{side}] has no Spacing=; assuming {DEFAULT_SPACING_MM:g} mm between "
                            f"{kind}s (tile {tile_mm:.3g} mm {extent}): give Spacing= and Units=")
    elif unspaced:
        wif.warnings.append(f"[{side} SPACING] gives no spacing for {unspaced} of {count} {kind}s and "
                            f"[{side}] has no Spacing=; assuming {DEFAULT_SPACING_MM:g} mm for them "
                            f"(tile {tile_mm:.3g} mm {extent})")


def _floating_warning(wif, missing: list[int], base: int, count: int, head: str, kind: str, tail: str) -> None:
    """Warn of threads the draft leaves out (``missing``, of ``count``), which float across
    the whole tile: ``head`` the threads (of ``kind``) ``(of count)``: ``tail``, whose
    ``{they}`` / ``{them}`` agree with their number."""
    if missing:
        one = len(missing) == 1
        tail = tail.format(they="it floats" if one else "they float", them="it" if one else "them")
        wif.warnings.append(f"{head} {_thread_list(missing, base, kind)} (of {count}): {tail}")


def _thread_list(indices: list[int], base: int, kind: str, most: int = 12) -> str:
    """``"warp ends 3, 5-7 and 9"`` (numbered as the file numbers them), the first ``most`` runs."""
    runs: list[list[int]] = []
    for i in indices:
        if runs and i == runs[-1][1] + 1:
            runs[-1][1] = i
        else:
            runs.append([i, i])
    text = [f"{a + base}" if a == b else f"{a + base}-{b + base}" for a, b in runs[:most]]
    if len(runs) > most:
        listed = ", ".join(text) + f", ... ({len(indices)} in all)"
    else:
        listed = text[0] if len(text) == 1 else ", ".join(text[:-1]) + " and " + text[-1]
    return f"{kind}{'s' if len(indices) > 1 else ''} {listed}"


def _interlacing_warning(drawdown: np.ndarray, threaded: np.ndarray, lift_source: str) -> str | None:
    """A warning if no thread of the draft interlaces: among the threaded warp ends, every pick
    is over all or under all of them (the picks lift none or all of the warp's shafts), or
    every end is over all picks or under all of them (every pick lifts the same shafts).
    Unthreaded ends have their own warning."""
    sub = drawdown[:, threaded]
    if sub.size == 0:
        return None
    rows_flat = bool(np.all(sub.all(axis=1) | ~sub.any(axis=1)))
    cols_flat = bool(np.all(sub.all(axis=0) | ~sub.any(axis=0)))
    if lift_source == "liftplan":
        where, lift = "[LIFTPLAN]", "every pick lifts"
    else:
        where, lift = "[TIEUP]", "the treadles of every pick lift"
    if rows_flat and cols_flat:
        state = "the warp over every pick" if sub.flat[0] else "every pick over the warp"
        return (f"{where}: no thread interlaces: {lift} {'all' if sub.flat[0] else 'none'} of the "
                f"shafts the warp is threaded on, so the tile is {state}, with no weave")
    if rows_flat:
        return (f"{where}: no weft pick interlaces with the warp: {lift} none or all of the shafts "
                f"the warp is threaded on, so each pick lies over or under every warp end across "
                f"the whole tile")
    if cols_flat:
        return (f"{where}: no warp end interlaces with the weft: {lift} the same shafts, so each "
                f"warp end lies over or under every pick across the whole tile")
    return None
