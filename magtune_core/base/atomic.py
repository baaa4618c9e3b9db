"""Safe outputs: atomic, durable file writes, and one writer per output.

Every file a user keeps (gains, tables, reports, recovered bags, metadata.yaml) is written
through :func:`atomic_write` or :func:`atomic_output`, so a failed write (disk full, quota,
``RLIMIT_FSIZE``, a signal) leaves the old file byte for byte and no partial file behind:
rename(2) within one directory is atomic on POSIX filesystems, and the data and the directory
entry are fsynced before and after it (the ext4/XFS ``rename`` durability recipe).

Every command that writes an output holds :func:`output_lock` on it for its whole run, so a
second command writing the same output is refused at once (one line naming the output and the
other writer's pid, exit 2) instead of both finishing and one result silently replacing the
other. See :func:`output_lock` for the lock file and why it is safe to remove.
"""
from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import stat
import tempfile
from pathlib import Path

from .errors import ConfigError
from .paramfile import check_path


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


#: The lock file of a directory output (inside it); a file output's is ``.<name>.magtune.lock`` beside it.
LOCK_NAME = ".magtune.lock"


def lock_file(path, directory: bool = True) -> Path:
    """The lock file of the output ``path``: ``path/.magtune.lock`` for a directory output,
    ``.<name>.magtune.lock`` beside a file output.

    Parameters
    ----------
    path : str or Path
        The output.
    directory : bool
        Whether the output is a directory.

    Returns
    -------
    Path
        The lock file's path.
    """
    path = Path(path)
    return path / LOCK_NAME if directory else path.parent / f".{path.name}{LOCK_NAME}"


def is_lock_file(name: str) -> bool:
    """Whether a directory entry called ``name`` is an output lock (:func:`lock_file`): the checks
    for an existing or non-empty output ignore it (a killed writer leaves it behind).

    Parameters
    ----------
    name : str
        A file name.

    Returns
    -------
    bool
        True for ``.magtune.lock`` and ``.<name>.magtune.lock``.
    """
    return name == LOCK_NAME or (name.startswith(".") and name.endswith(LOCK_NAME))


def output_entries(directory) -> list[Path]:
    """The entries of an output directory other than lock files (empty if it does not exist).

    Parameters
    ----------
    directory : str or Path
        The directory.

    Returns
    -------
    list of Path
        Its entries, lock files left out.
    """
    d = Path(directory)
    return [e for e in d.iterdir() if not is_lock_file(e.name)] if d.is_dir() else []


def _make_directories(directory: Path, path: Path, option: str) -> list[Path]:
    """Create ``directory`` and its missing parents; the ones created, outermost first."""
    missing = []
    d = directory
    while not d.exists() and d != d.parent:
        missing.append(d)
        d = d.parent
    created = []
    for d in reversed(missing):
        try:
            d.mkdir()
        except FileExistsError:
            continue
        except OSError as exc:
            _remove_empty(created)
            raise ConfigError(path, None, f"cannot create {d}: {exc.strerror or exc} (choose another {option})") from None
        created.append(d)
    return created


def _remove_empty(created: list[Path]) -> None:
    """Remove the directories a lock created, innermost first, if nothing was written into them."""
    for d in reversed(created):
        try:
            d.rmdir()
        except OSError:
            return


def _same_file(fd: int, lock: Path) -> bool:
    """Whether ``lock`` still names the file open as ``fd`` (a finishing writer removes its lock file)."""
    try:
        st = os.stat(lock, follow_symlinks=False)
    except FileNotFoundError:
        return False
    own = os.fstat(fd)
    return (st.st_dev, st.st_ino) == (own.st_dev, own.st_ino)


def _holder(fd: int) -> str:
    """Who holds the lock, from the lock file's content (``<pid> <command>``), printable only."""
    try:
        text = os.pread(fd, 200, 0).decode("ascii", "replace")
    except OSError:
        text = ""
    line = text.splitlines()[0] if text.strip() else ""
    pid, _, command = "".join(c for c in line if c.isprintable()).partition(" ")
    if not pid.isdigit():
        return "another command (pid unknown)"
    return f"{command.strip() or 'another command'} (pid {pid})"


def _open_lock(lock: Path, path: Path, option: str) -> int | None:
    """The lock file opened (created if absent; never through a symbolic link); None if its
    directory vanished (removed by a writer that just finished: the caller makes it again)."""
    try:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC, 0o644)
    except FileNotFoundError:
        return None
    except OSError as exc:
        why = ("is a symbolic link" if exc.errno == errno.ELOOP else (exc.strerror or str(exc)))
        raise ConfigError(path, None, f"cannot use the lock file {lock.name}: {why} (remove it, or choose another "
                                      f"{option})") from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise ConfigError(path, None, f"the lock file {lock.name} is not a regular file (remove it, or choose "
                                      f"another {option})")
    return fd


def _acquire(lock: Path, path: Path, owner: str, option: str) -> int:
    """The descriptor holding the exclusive lock of ``lock``; ConfigError naming the holder if taken."""
    for _ in range(20):
        fd = _open_lock(lock, path, option)
        if fd is None:
            lock.parent.mkdir(parents=True, exist_ok=True)
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            holder = _holder(fd) if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN) else ""
            os.close(fd)
            if holder:
                raise ConfigError(path, None, f"is being written by {holder}; wait until it ends, or choose "
                                              f"another {option}") from None
            raise ConfigError(path, None, f"cannot lock {lock.name}: {exc.strerror or exc} (choose another "
                                          f"{option})") from None
        if _same_file(fd, lock):
            with contextlib.suppress(OSError):  # who holds it, for the next writer's message only
                os.ftruncate(fd, 0)
                os.pwrite(fd, f"{os.getpid()} {owner}\n".encode(), 0)
            return fd
        os.close(fd)  # locked a file its writer had just removed: take the new one
    raise ConfigError(path, None, f"cannot lock {lock.name}: it keeps being replaced (choose another {option})")


@contextlib.contextmanager
def output_lock(path, owner: str, *, directory: bool = True, option: str = "--out"):
    """Hold the exclusive lock of the output ``path`` while the block runs (one writer per output).

    The lock is ``flock`` on :func:`lock_file` (created, with its directories, if absent; a
    directory output is created here). Its content is ``<pid> <owner>``, for the message a second
    writer gets. At the end the lock file is removed before it is unlocked, and so are the
    directories created here if nothing was written into them; a writer that locked the removed
    file sees that the name now points elsewhere and takes the new file. The lock dies with the
    process (``kill -9`` included); a lock file left behind is taken by the next writer, and the
    checks for an existing output ignore it (:func:`is_lock_file`).

    Parameters
    ----------
    path : str or Path
        The output directory (``directory=True``) or file.
    owner : str
        Who writes, e.g. ``magtune campaign``.
    directory : bool
        Whether ``path`` is a directory output.
    option : str
        The command-line option that chooses ``path``, named in the messages.

    Yields
    ------
    Path
        The lock file.

    Raises
    ------
    ConfigError
        Another process holds the lock (one line naming ``path`` and its pid and command), or
        the lock file or its directory cannot be created.
    """
    path = Path(path)
    check_path(path, option)  # a symbolic link loop: the usual one line
    if directory and path.exists() and not path.is_dir():
        raise ConfigError(path, None, f"exists and is not a directory (choose another {option})")
    if not directory and path.is_dir():
        raise ConfigError(path, None, f"is a directory; {option} expects a file name")
    lock = lock_file(path, directory)
    created = _make_directories(lock.parent, path, option)
    try:
        fd = _acquire(lock, path, owner, option)
    except BaseException:
        _remove_empty(created)
        raise
    try:
        yield lock
    finally:
        if _same_file(fd, lock):
            with contextlib.suppress(FileNotFoundError):
                os.unlink(lock)
        os.close(fd)
        _remove_empty(created)
