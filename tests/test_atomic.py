"""Atomic writes (mscloth/atomic.py): the mode a plain write gives, and checking an output
folder before the work that fills it."""
import os
import re
import stat

import mitsuba as mi
import numpy as np
import pytest

from mscloth.atomic import atomic_write, check_writable, temporary_directory
from mscloth.errors import ClothError


def _mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


@pytest.fixture(params=[0o022, 0o027])
def umask(request):
    old = os.umask(request.param)
    yield request.param
    os.umask(old)


def test_new_files_get_the_umask_mode_and_overwritten_ones_keep_theirs(tmp_path, umask):
    new = tmp_path / "sub" / "new.json"
    atomic_write(new, lambda f: f.write(b"{}"))
    assert new.read_bytes() == b"{}" and _mode(new) == 0o666 & ~umask
    old = tmp_path / "old.xml"
    old.write_text("<scene/>")
    for mode in (0o644, 0o640, 0o600):
        os.chmod(old, mode)
        atomic_write(old, lambda f: f.write(b"<scene version='3.0.0'/>"))
        assert _mode(old) == mode and old.read_bytes() == b"<scene version='3.0.0'/>"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.xml", "sub"]  # no temporaries left


def test_images_written_by_mitsuba_get_the_umask_mode(tmp_path, umask):
    from mscloth.render import write_images

    exr, png = write_images(mi.TensorXf(np.full((4, 4, 3), 0.5, dtype=np.float32)), tmp_path / "img.exr")
    assert _mode(exr) == _mode(png) == 0o666 & ~umask
    os.chmod(png, 0o644)
    write_images(mi.TensorXf(np.zeros((4, 4, 3), dtype=np.float32)), exr)
    assert _mode(png) == 0o644


def test_temporaries_are_named_as_the_cache_expects_and_directories_get_the_umask_mode(tmp_path, umask):
    seen = []
    atomic_write(tmp_path / "tables-x.npz", lambda f: seen.append(os.path.basename(f.name)))
    assert re.fullmatch(r"\.tables-x\.[a-z0-9_]{8}\.npz", seen[0]), seen
    directory = temporary_directory(tmp_path, ".maps.")
    assert directory.is_dir() and re.fullmatch(r"\.maps\.[a-z0-9_]{8}", directory.name)
    assert _mode(directory) == 0o777 & ~umask


def test_failed_write_leaves_the_target_alone(tmp_path):
    target = tmp_path / "keep.txt"
    target.write_text("old")

    def broken(f):
        f.write(b"half")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        atomic_write(target, broken)
    assert target.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["keep.txt"]


def test_check_writable_names_the_users_path(tmp_path):
    check_writable(tmp_path / "new" / "dir")
    assert (tmp_path / "new" / "dir").is_dir() and not any((tmp_path / "new" / "dir").iterdir())
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    with pytest.raises(ClothError, match=f"cannot write {re.escape(str(blocker / 'x.exr'))}: "):
        check_writable(blocker, target=blocker / "x.exr")
