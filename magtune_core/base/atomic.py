"""Atomic, durable file writes: a temporary file in the same directory, fsync, rename.

Every file a user keeps (gains, tables, reports, recovered bags, metadata.yaml) is written
through :func:`atomic_write` or :func:`atomic_output`, so a failed write (disk full, quota,
``RLIMIT_FSIZE``, a signal) leaves the old file byte for byte and no partial file behind:
rename(2) within one directory is atomic on POSIX filesystems, and the data and the directory
entry are fsynced before and after it (the ext4/XFS ``rename`` durability recipe).
"""
from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path


def _fsync_dir(directory: Path) -> None:
    """fsync a directory so a rename in it survives a crash (no-op where directories cannot be opened)."""
    try:
        fd = os.open(directory, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_output(path, mode: str = "w", *, overwrite: bool = True, encoding: str = "utf-8"):
    """Open a temporary file beside ``path`` for writing; on a clean exit fsync it and rename it
    onto ``path``; on any exception remove it and leave ``path`` as it was.

    ``mode`` "w" (text) or "wb"; ``overwrite=False`` raises FileExistsError when ``path`` exists
    (checked again just before the rename). The new file gets the old file's permission bits, or
    0o666 minus the umask for a new file.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"mode must be 'w' or 'wb', got {mode!r}")
    path = Path(path)
    if not overwrite and path.exists():
        raise FileExistsError(f"{path} exists")
    directory = path.parent if str(path.parent) else Path(".")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
    try:
        try:
            perm = path.stat().st_mode & 0o7777
        except FileNotFoundError:
            umask = os.umask(0)
            os.umask(umask)
            perm = 0o666 & ~umask
        os.fchmod(fd, perm)
        kw = {} if "b" in mode else {"encoding": encoding, "newline": ""}
        with os.fdopen(fd, mode, **kw) as fh:
            fd = -1
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        if not overwrite and path.exists():
            raise FileExistsError(f"{path} exists")
        os.replace(tmp, path)
        tmp = None
        _fsync_dir(directory)
    finally:
        if fd >= 0:
            os.close(fd)
        if tmp is not None:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)


def atomic_write(path, data, *, overwrite: bool = True, encoding: str = "utf-8") -> Path:
    """Write ``data`` (str or bytes) to ``path`` atomically (:func:`atomic_output`).

    Returns
    -------
    Path
        ``path``.
    """
    with atomic_output(path, "wb" if isinstance(data, (bytes, bytearray, memoryview)) else "w",
                       overwrite=overwrite, encoding=encoding) as fh:
        fh.write(data)
    return Path(path)


def atomic_savefig(fig, path, **kwargs) -> Path:
    """Save a matplotlib figure atomically: render into memory, then :func:`atomic_write`
    (``savefig`` writes in place, so a failure would leave a truncated image).

    Returns
    -------
    Path
        ``path``.
    """
    import io

    path = Path(path)
    buf = io.BytesIO()
    kwargs.setdefault("format", path.suffix.lstrip(".") or "png")
    fig.savefig(buf, **kwargs)
    return atomic_write(path, buf.getvalue())
