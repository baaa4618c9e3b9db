"""magtune_core.base.atomic.output_lock (one writer per output) and the regular-file, bounded reads of
magtune_core.base.paramfile (issue 45)."""
from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest

from magtune_core.base.atomic import LOCK_NAME, is_lock_file, lock_file, output_entries, output_lock
from magtune_core.base.errors import ConfigError
from magtune_core.base.paramfile import USER_FILE_LIMIT, is_regular_file, read_user_text

TRY_LOCK = "from magtune_core.base.atomic import output_lock\nwith output_lock({path!r}, 'probe'): pass\n"


def test_second_writer_in_another_process_is_refused_naming_the_first(tmp_path):
    out = tmp_path / "mc"
    with output_lock(out, "magtune campaign") as lock:
        assert lock == out / LOCK_NAME and out.is_dir()
        assert lock.read_text() == f"{os.getpid()} magtune campaign\n"
        r = subprocess.run([sys.executable, "-c", TRY_LOCK.format(path=str(out))], capture_output=True, text=True,
                           timeout=60)
        assert r.returncode != 0
        assert f"{out}: is being written by magtune campaign (pid {os.getpid()})" in r.stderr
    # released: the lock file and the directory made for it are gone, another process takes it
    assert not out.exists()
    r = subprocess.run([sys.executable, "-c", TRY_LOCK.format(path=str(out))], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0, r.stderr


def test_lock_is_exclusive_within_one_process_and_released_on_error(tmp_path):
    out = tmp_path / "v"
    out.mkdir()
    with pytest.raises(RuntimeError), output_lock(out, "first"):
        with pytest.raises(ConfigError, match=rf"{out}: is being written by first \(pid {os.getpid()}\); wait until "
                                              r"it ends, or choose another --out"):
            with output_lock(out, "second"):
                pass
        raise RuntimeError("the command failed")
    assert out.is_dir() and list(out.iterdir()) == []  # kept (not made here), lock file removed
    with output_lock(out, "third"):
        pass


def test_stale_lock_file_is_taken_and_ignored_by_output_checks(tmp_path):
    out = tmp_path / "r"
    out.mkdir()
    (out / LOCK_NAME).write_text("999999999 magtune report\n")  # left by a killed writer: no flock held
    (out / "summary.md").write_text("old\n")
    assert output_entries(out) == [out / "summary.md"]
    assert is_lock_file(LOCK_NAME) and is_lock_file(".sigma_60.yaml.magtune.lock") and not is_lock_file("x.lock")
    with output_lock(out, "magtune report") as lock:
        assert lock.read_text() == f"{os.getpid()} magtune report\n"
    assert sorted(p.name for p in out.iterdir()) == ["summary.md"]


def test_file_output_lock_sits_beside_the_file(tmp_path):
    out = tmp_path / "gains" / "sigma_60.yaml"
    assert lock_file(out, directory=False) == tmp_path / "gains" / ".sigma_60.yaml.magtune.lock"
    with output_lock(out, "magtune tune", directory=False):
        with pytest.raises(ConfigError, match="is being written by magtune tune"):
            with output_lock(out, "magtune verify --record", directory=False, option="GAINS"):
                pass
        with output_lock(tmp_path / "gains" / "sigma_120.yaml", "magtune tune", directory=False):
            pass  # another file of the same directory: another output
    assert not (tmp_path / "gains").exists()  # nothing was written: the directory made for the lock is gone


def test_lock_refuses_symlinked_lock_file_and_wrong_kind_of_output(tmp_path):
    out = tmp_path / "o"
    out.mkdir()
    (out / LOCK_NAME).symlink_to(tmp_path / "elsewhere")
    with pytest.raises(ConfigError, match="lock file .magtune.lock: is a symbolic link"):
        with output_lock(out, "x"):
            pass
    assert not (tmp_path / "elsewhere").exists()
    f = tmp_path / "plain"
    f.write_text("")
    with pytest.raises(ConfigError, match="exists and is not a directory"):
        with output_lock(f, "x"):
            pass
    with pytest.raises(ConfigError, match="is a directory; --out expects a file name"):
        with output_lock(out, "x", directory=False):
            pass


def test_fifo_and_device_are_refused_before_reading(tmp_path):
    fifo = tmp_path / "gains.yaml"
    os.mkfifo(fifo)
    link = tmp_path / "zero.yaml"
    link.symlink_to("/dev/zero")
    t0 = time.monotonic()
    with pytest.raises(ConfigError, match=rf"{fifo}: is a FIFO \(named pipe\), not a regular file"):
        read_user_text(fifo)
    with pytest.raises(ConfigError, match=rf"{link}: is a symbolic link to a character device \(/dev/zero\), not a "
                                          "regular file"):
        read_user_text(link)
    assert time.monotonic() - t0 < 1.0
    assert is_regular_file(tmp_path / "missing") is False
    with pytest.raises(ConfigError, match="FIFO"):
        is_regular_file(fifo)


def test_size_limit_is_checked_before_reading(tmp_path):
    ok = tmp_path / "ok.yaml"
    ok.write_bytes(b"a: 1\n" + b"#" * (USER_FILE_LIMIT - 6) + b"\n")
    assert len(read_user_text(ok)) == USER_FILE_LIMIT
    big = tmp_path / "big.yaml"
    big.write_bytes(b"#" * (USER_FILE_LIMIT + 1))
    with pytest.raises(ConfigError, match=rf"{big}: too large \({USER_FILE_LIMIT + 1} bytes\): input files are "
                                          r"limited to 1 MiB"):
        read_user_text(big)
