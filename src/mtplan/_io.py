"""Atomic file writes: write to a temporary file beside the target, then rename."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

__all__ = ["atomic_write", "atomic_write_text", "output_problem"]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_MODE = 0o666 & ~_umask()


@contextlib.contextmanager
def atomic_write(path, mode: str = "w", **kwargs):
    """Open a temporary file beside `path`; on success rename it over `path`.

    An exception (or a killed process) leaves `path` untouched and no partial file
    behind (the temporary file is removed on exceptions).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, mode, **kwargs) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, _MODE)  # mkstemp creates 0600; give the file the usual permissions
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def atomic_write_text(path, text: str) -> None:
    """Write `text` to `path` atomically (UTF-8)."""
    with atomic_write(path, "w", encoding="utf-8") as fh:
        fh.write(text)


def output_problem(path, *, folder: bool = False) -> str | None:
    """Why `path` cannot be written as an output file (or folder), or None when it can.

    Checked before any work, so that a long computation does not end in a refusal: the
    path is not empty; a file output is not an existing folder, a folder output not an
    existing file; the nearest existing parent is a writable folder (missing folders are
    created on writing); an existing output is writable.
    """
    text = str(path)
    if not text.strip():
        return "the output path is empty"
    path = Path(path)
    if path.exists():
        if folder and not path.is_dir():
            return f"{text!r} is an existing file, not a folder"
        if not folder and path.is_dir():
            return f"{text!r} is a folder, not a file"
        if not os.access(path, os.W_OK):
            return f"{text!r} is not writable"
    parent = path.parent if not (folder and path.is_dir()) else path
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        return f"cannot create {text!r}: {str(parent)!r} is a file, not a folder"
    if not os.access(parent, os.W_OK | os.X_OK):
        return f"cannot write {text!r}: the folder {str(parent)!r} is not writable"
    return None
