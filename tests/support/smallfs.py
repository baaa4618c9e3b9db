"""A small, really full filesystem for tests of disk-full handling: a tmpfs mounted on a fresh
directory (root only; the test is skipped with the reason otherwise) and a filler file that takes
its last byte."""
from __future__ import annotations

import contextlib
import errno
import os
import shutil
import subprocess

import pytest


@contextlib.contextmanager
def small_tmpfs(directory, size: str = "64k"):
    """Mount a tmpfs of ``size`` on the new directory ``directory``; unmount it afterwards."""
    directory.mkdir()
    if shutil.which("mount") is None:
        pytest.skip("no mount command")
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(directory)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({r.stderr.strip() or 'not permitted'})")
    try:
        yield directory
    finally:
        subprocess.run(["umount", "-l", str(directory)], check=False)


def fill(directory):
    """Fill the filesystem of ``directory`` up to the last byte (ENOSPC); returns the filler file."""
    path = directory / "filler"
    fd = os.open(path, os.O_WRONLY | os.O_CREAT)
    try:
        while True:
            os.write(fd, b"\0" * 512)
    except OSError as exc:
        assert exc.errno == errno.ENOSPC
    finally:
        os.close(fd)
    return path
