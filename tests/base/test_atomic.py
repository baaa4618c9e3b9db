"""base.atomic: the old file survives a failed write byte for byte, and nothing partial is left."""
from __future__ import annotations

import os
import resource
import signal

import pytest

from magtune_core.base.atomic import atomic_output, atomic_write


def test_replaces_and_keeps_permissions(tmp_path):
    p = tmp_path / "g.yaml"
    atomic_write(p, "one\n")
    os.chmod(p, 0o640)
    atomic_write(p, b"two\n")
    assert p.read_bytes() == b"two\n"
    assert p.stat().st_mode & 0o777 == 0o640
    assert os.listdir(tmp_path) == ["g.yaml"]


def test_no_overwrite_without_flag(tmp_path):
    p = tmp_path / "g.yaml"
    atomic_write(p, "one\n")
    with pytest.raises(FileExistsError):
        atomic_write(p, "two\n", overwrite=False)
    assert p.read_text() == "one\n"


def test_exception_inside_leaves_old_file(tmp_path):
    p = tmp_path / "g.yaml"
    atomic_write(p, "good\n")
    with pytest.raises(RuntimeError), atomic_output(p) as fh:
        fh.write("half")
        raise RuntimeError("interrupted")
    assert p.read_text() == "good\n" and os.listdir(tmp_path) == ["g.yaml"]


def test_file_size_limit_leaves_old_file(tmp_path):
    """A write past RLIMIT_FSIZE fails with EFBIG (SIGXFSZ ignored, as Python does not by default)."""
    p = tmp_path / "g.yaml"
    atomic_write(p, "good\n" * 10)
    before = p.read_bytes()
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    old = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    try:
        resource.setrlimit(resource.RLIMIT_FSIZE, (1024, hard))
        with pytest.raises(OSError):
            atomic_write(p, "x" * 100_000)
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
        signal.signal(signal.SIGXFSZ, old)
    assert p.read_bytes() == before and os.listdir(tmp_path) == ["g.yaml"]


def _gains_file(tmp_path):
    from magtune_core.design.gains import load_gains, save_gains

    p = tmp_path / "sigma_60.yaml"
    g = load_gains(ROOT / "config" / "gains" / "sigma_60.yaml")
    save_gains(p, g)
    return p, g, save_gains


ROOT = __import__("pathlib").Path(__file__).resolve().parents[2]


def test_save_gains_force_under_file_size_limit_keeps_old_file(tmp_path):
    """Why: ``tune --force`` (save_gains) under a file-size limit truncated the good file."""
    p, g, save_gains = _gains_file(tmp_path)
    before = p.read_bytes()
    g.provenance["design"] = {"note": "x" * 50_000}  # a file far past the limit
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    old = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    try:
        resource.setrlimit(resource.RLIMIT_FSIZE, (4096, hard))
        with pytest.raises(OSError):
            save_gains(p, g)
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
        signal.signal(signal.SIGXFSZ, old)
    assert p.read_bytes() == before and os.listdir(tmp_path) == [p.name]


@pytest.fixture
def full_tmpfs(tmp_path):
    """A 64 kB tmpfs (tests/support/smallfs.py), unmounted afterwards."""
    from smallfs import small_tmpfs

    with small_tmpfs(tmp_path / "small") as mnt:
        yield mnt


def test_save_gains_on_full_filesystem_keeps_old_file(tmp_path, full_tmpfs):
    """Why: a full disk during ``tune --force`` left a truncated gains file."""
    from magtune_core.design.gains import load_gains, save_gains

    p = full_tmpfs / "sigma_60.yaml"
    g = load_gains(ROOT / "config" / "gains" / "sigma_60.yaml")
    save_gains(p, g)
    before = p.read_bytes()
    from smallfs import fill

    fill(full_tmpfs)
    g.provenance["design"] = {"note": "x" * 20_000}
    with pytest.raises(OSError):
        save_gains(p, g)
    assert p.read_bytes() == before
    assert sorted(os.listdir(full_tmpfs)) == ["filler", p.name]  # no temporary file left
    assert load_gains(p).K.tolist() == g.K.tolist()

