"""Writing files so that a reader never sees a half-written one.

Everything goes to a temporary file beside the target and is moved into place
with ``os.replace`` (atomic on one filesystem); on any error the temporary file
is removed and the target is left as it was.

The result has the mode a plain ``open(path, "w")`` would give it: 0666 less the umask
for a new file, the old file's mode for one overwritten (``tempfile.mkstemp`` makes 0600
files, which a rename would hand on to every image, scene and map written).
"""
from __future__ import annotations

import contextlib
import os
import secrets
import stat
from pathlib import Path

from .errors import ClothError

#: Characters of the 8 random ones in temporary names (as ``tempfile``'s; mscloth.cache
#: recognises ``.<stem>.<8 of these><suffix>`` as the leftover of an interrupted write).
_NAME_CHARACTERS = "abcdefghijklmnopqrstuvwxyz0123456789_"


def _create_beside(parent: Path, prefix: str, suffix: str, create) -> Path:
    """A new ``parent/<prefix><8 random characters><suffix>`` made by ``create(path)``,
    which must fail with FileExistsError if the name is taken."""
    for _ in range(100):
        name = "".join(secrets.choice(_NAME_CHARACTERS) for _ in range(8))
        candidate = parent / f"{prefix}{name}{suffix}"
        try:
            create(candidate)
        except FileExistsError:
            continue
        return candidate
    raise FileExistsError(f"no free temporary name {prefix}XXXXXXXX{suffix} in {parent}")


def _create_file(path: Path) -> None:
    # Mode 0666: the kernel takes the umask off, as for any new file.
    os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))


def check_writable(directory, target=None) -> None:
    """Raise ClothError unless files can be created in ``directory`` (made if missing): a
    command checks its output before spending minutes on what it would write. The error
    names ``target`` (the user's output path) when given, else the directory."""
    directory = Path(directory)
    try:
        directory.mkdir(parents=True, exist_ok=True)
        os.unlink(_create_beside(directory, ".mscloth-write-test-", "", _create_file))
    except OSError as error:
        what = f"write {target}" if target is not None else f"write to {directory}"
        raise ClothError(f"cannot {what}: {error.strerror or error}") from None


def temporary_directory(parent, prefix: str) -> Path:
    """A new empty directory ``parent/<prefix><8 random characters>`` with the mode
    ``mkdir`` gives (0777 less the umask; ``tempfile.mkdtemp`` makes 0700), to fill and
    rename into place."""
    return _create_beside(Path(parent), prefix, "", lambda p: os.mkdir(p, 0o777))


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path (same directory and suffix as ``path``) to write;
    it replaces ``path`` when the block ends without error."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = str(_create_beside(path.parent, f".{path.stem}.", path.suffix, _create_file))
    try:
        try:
            mode = stat.S_IMODE(os.stat(path).st_mode)  # an overwritten file keeps its mode
        except FileNotFoundError:
            mode = stat.S_IMODE(os.stat(tmp).st_mode)  # 0666 less the umask
        yield tmp
        # Set last: a writer may have replaced the file it was given.
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def atomic_write(path, write) -> None:
    """Call ``write(binary_file)`` on a temporary file, flush it to disk, move it to ``path``."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
