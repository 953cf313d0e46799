"""The on-disk cache (mscloth/cache.py) and `mscloth cache`: what it lists, what it removes
(mscloth's files only), and that loads mark entries as used."""
import os
import re
import subprocess
import sys
import time

import numpy as np
import pytest

from mscloth.cache import cache_entries, mark_used, remove_entries
from mscloth.cli import main

KEY = "ab" * 32


def _write(path, size, age_days=0.0):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"x" * size)
    stamp = time.time() - age_days * 86400.0
    os.utime(path, (stamp, stamp))
    return path


@pytest.fixture
def cache_dir(tmp_path, monkeypatch):
    root = tmp_path / "cache"
    monkeypatch.setenv("MSCLOTH_CACHE", str(root))
    _write(root / f"tables-{KEY}.npz", 1000, age_days=40)
    _write(root / f"tables-{KEY}.json", 10, age_days=40)
    _write(root / f"tables-{'cd' * 32}.npz", 500, age_days=1)  # its sidecar never written
    _write(root / f".tables-{'ef' * 32}.a1b2c3d4.npz", 300, age_days=50)  # a killed write
    _write(root / "references" / f"plane-320x180-1024spp-{'0' * 16}.npz", 200, age_days=10)
    _write(root / "scenes" / f"drape-{'1' * 12}.ply", 100, age_days=60)
    # Not mscloth's: names it does not write, and a user's own files.
    for name in ("notes.txt", "tables-mine.npz", f"tables-{KEY}.npz.bak", "references/keep.npz",
                 "scenes/my-scene.ply"):
        _write(root / name, 7, age_days=100)
    return root


def test_entries_are_mscloth_files_grouped_by_item(cache_dir):
    entries = cache_entries(cache_dir)
    by_name = {e.name: e for e in entries}
    assert sorted((e.kind, e.size, e.unfinished) for e in entries) == [
        ("references", 200, False), ("scene meshes", 100, False),
        ("tables", 300, True), ("tables", 500, False), ("tables", 1010, False)]
    table = by_name[f"tables-{KEY}"]
    assert {p.name for p in table.paths} == {f"tables-{KEY}.npz", f"tables-{KEY}.json"}
    assert abs(table.last_used - (time.time() - 40 * 86400)) < 60
    assert cache_entries(cache_dir / "nowhere") == []


def test_clear_removes_only_mscloth_files(cache_dir, capsys):
    assert main(["cache", "--clear", "--dry-run"]) == 0
    assert "would remove 5 entries" in capsys.readouterr().out
    assert len(cache_entries(cache_dir)) == 5  # a dry run removes nothing
    assert main(["cache", "--clear"]) == 0
    assert "removed 5 entries" in capsys.readouterr().out
    left = sorted(str(p.relative_to(cache_dir)) for p in cache_dir.rglob("*") if p.is_file())
    assert left == sorted(["notes.txt", "tables-mine.npz", f"tables-{KEY}.npz.bak", "references/keep.npz",
                           "scenes/my-scene.ply"])


def test_clear_older_than_keeps_recently_used_entries(cache_dir, capsys):
    mark_used(*cache_entries(cache_dir)[-1].paths)  # the scene mesh (60 days old) was just used
    assert main(["cache", "--clear", "--older-than", "30"]) == 0
    assert "removed 2 entries unused for 30 days" in capsys.readouterr().out
    assert sorted(e.size for e in cache_entries(cache_dir)) == [100, 200, 500]


def test_listing_and_bad_arguments(cache_dir, capsys):
    assert main(["cache", "--list"]) == 0
    out = capsys.readouterr().out
    assert str(cache_dir) in out and f"tables-{KEY}" in out and "an interrupted write" in out
    assert re.search(r"total\s+5 entries\s+2\.1 KiB", out), out
    for bad in (["cache", "--clear", "--older-than", "-1"], ["cache", "--clear", "--older-than", "soon"],
                ["cache", "--older-than", "3"]):
        assert main(bad) == 2
        assert "--older-than" in capsys.readouterr().err
    assert len(cache_entries(cache_dir)) == 5
    # --dry-run without --clear is refused as --older-than is (it was silently ignored)
    assert main(["cache", "--dry-run"]) == 2
    assert "--dry-run only lists what --clear would remove: add --clear" in capsys.readouterr().err


def test_one_entry_is_singular(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("MSCLOTH_CACHE", str(tmp_path))
    _write(tmp_path / f"tables-{KEY}.npz", 100)
    assert main(["cache"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"tables\s+1 entry\s+0\.1 KiB", out) and "entries" not in out, out
    assert main(["cache", "--clear", "--dry-run"]) == 0
    assert "would remove 1 entry (" in capsys.readouterr().out
    assert main(["cache", "--clear"]) == 0
    assert "removed 1 entry (" in capsys.readouterr().out


@pytest.mark.parametrize("below", ["", "sub"])
def test_a_cache_that_is_a_file_is_one_line(tmp_path, monkeypatch, capsys, below):
    """MSCLOTH_CACHE naming a file (or a path under one): `cache` said "(not created yet)"
    and `render` failed with a raw "[Errno 20] Not a directory"."""
    from mscloth.cache import default_cache_dir
    from mscloth.errors import ClothError

    blocker = tmp_path / "cache"
    blocker.write_text("not a folder")
    monkeypatch.setenv("MSCLOTH_CACHE", str(blocker / below) if below else str(blocker))
    with pytest.raises(ClothError, match="MSCLOTH_CACHE=.* not a folder"):
        default_cache_dir()
    for command in (["cache"], ["cache", "--list"], ["render", "plane", "--spp", "1", "--res", "8x8",
                                                     "--out", str(tmp_path / "p.exr")]):
        if command[0] == "render":  # a fresh process: this one may hold the plane's tables in memory
            result = subprocess.run([sys.executable, "-m", "mscloth", *command], capture_output=True, text=True,
                                    timeout=300)
            code, err = result.returncode, result.stderr
        else:
            code, err = main(command), capsys.readouterr().err
        assert code == 2
        lines = [line for line in err.splitlines() if line.strip()]
        assert len(lines) == 1 and f"MSCLOTH_CACHE={blocker}" in lines[0] and "a file, not a folder" in lines[0], err
    assert blocker.read_text() == "not a folder" and not (tmp_path / "p.exr").exists()


def test_a_reader_that_stops_early_ends_the_listing_quietly(tmp_path):
    """`mscloth cache --list | head -3`: the reader closes the pipe; mscloth stops without an
    error, with 141 (128 + SIGPIPE) as ls does. Both a write that fails mid-listing (more
    than the pipe's buffer) and one that fails at the final flush."""
    many = tmp_path / "many"
    for i in range(400):
        _write(many / f"tables-{i:064x}.npz", 10)
    for root in (many, tmp_path / "empty"):
        child = subprocess.Popen([sys.executable, "-m", "mscloth", "cache", "--list"], stdout=subprocess.PIPE,
                                 stderr=subprocess.PIPE, env={**os.environ, "MSCLOTH_CACHE": str(root)})
        child.stdout.close()  # before mscloth writes anything
        err = child.stderr.read().decode()
        assert child.wait(timeout=120) == 141, err
        assert err == "", err


def test_remove_entries_skips_files_already_gone(cache_dir):
    entries = cache_entries(cache_dir)
    gone = entries[0].paths[0]
    size = gone.stat().st_size
    gone.unlink()
    assert remove_entries(entries) == sum(e.size for e in entries) - size
    assert cache_entries(cache_dir) == []


def test_loading_cached_tables_marks_them_used(tmp_path):
    """A load refreshes the entry's time, so --older-than removes what nothing reads."""
    from mscloth.maps.woven import woven_maps
    from mscloth.patterns.weaves import plain
    from mscloth.precompute.tables import load_or_build

    maps = woven_maps(plain(), 16)
    kw = dict(dr=2, dv=2, clusters=2, progress=False)
    load_or_build(maps, 0.3, cache_dir=tmp_path, **kw)
    (entry,) = cache_entries(tmp_path)
    old = time.time() - 90 * 86400.0
    for path in entry.paths:
        os.utime(path, (old, old))
    tables = load_or_build(maps, 0.3, cache_dir=tmp_path, **kw)
    (entry,) = cache_entries(tmp_path)
    assert entry.last_used > time.time() - 3600 and tables.key in entry.name
    assert np.all(np.isfinite(tables.d_sat))


def test_scene_maps_directories_and_hyphenated_scene_references_are_entries(tmp_path, capsys, monkeypatch):
    """The built-in scenes' maps directories (one entry each, removed with their files) and
    the references of scenes named with a hyphen (``satin-plane``)."""
    from mscloth.scenes.builtin import scene_maps

    root = tmp_path / "cache"
    monkeypatch.setenv("MSCLOTH_CACHE", str(root))
    maps = scene_maps("plain_maps", {"pattern": "plain", "resolution": 8, "yarn_width": 1.0})
    assert scene_maps("plain_maps", {"pattern": "plain", "resolution": 8, "yarn_width": 1.0}) == maps
    _write(root / "scenes" / f".plain_maps-{'2' * 12}.ab12cd34" / "maps.npz", 50)  # a killed write
    _write(root / "references" / f"satin-plane-320x180-1024spp-{'0' * 16}.npz", 200)
    _write(root / "scenes" / "my-maps" / "maps.npz", 7)  # not mscloth's
    entries = cache_entries(root)
    assert sorted((e.kind, e.unfinished) for e in entries) == [
        ("references", False), ("scene maps", False), ("scene maps", True)]
    (done,) = [e for e in entries if e.kind == "scene maps" and not e.unfinished]
    assert str(done.directory) == maps and {p.name for p in done.paths} == {"maps.npz", "maps.json"}
    assert main(["cache", "--clear"]) == 0
    assert "removed 3 entries" in capsys.readouterr().out
    left = sorted(str(p.relative_to(root)) for p in root.rglob("*"))
    assert left == ["references", "scenes", "scenes/my-maps", "scenes/my-maps/maps.npz"]


def test_stored_sky_shares_are_entries(tmp_path):
    """The pilot's stored shares (``sky_shares/<key>.json``) are listed and removable;
    other files there are not mscloth's."""
    root = tmp_path / "cache"
    _write(root / "sky_shares" / f"{KEY}.json", 120, age_days=3)
    _write(root / "sky_shares" / "mine.json", 7)
    entries = cache_entries(root)
    assert [(e.kind, e.name, e.size) for e in entries] == [("sky shares", KEY, 120)]
    assert remove_entries(entries) == 120
    assert [p.name for p in (root / "sky_shares").iterdir()] == ["mine.json"]
