"""Domain lock files (magtune_core.ros.process.DomainLock, issue 32 item 5): machine-wide, but a
lock file that is a symlink or belongs to another user is treated as taken and never written,
and an existing lock file is never truncated.

The lock directory is the temp directory; the tests point ``tempfile.tempdir`` at their own
directory so that planting files there touches no other run's locks (the opening code is the same).
"""
from __future__ import annotations

import os
import tempfile

import pytest

from magtune_core.base.errors import SilError
from magtune_core.ros import process

CONTENT = b"precious data that a lock must never truncate\n"


@pytest.fixture
def lockdir(tmp_path, monkeypatch):
    d = tmp_path / "tmp"
    d.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(d))
    assert process.lock_path(215).parent == d
    return d


def test_symlinked_lock_is_skipped_and_its_target_untouched(lockdir, tmp_path):
    """Every domain id but one is a planted symlink to a file with known content: the lock takes
    the one regular id, the target is byte-identical, and asking for a planted id fails."""
    target = tmp_path / "victim.txt"
    target.write_bytes(CONTENT)
    free = 220
    for did in process.DOMAIN_RANGE:
        if did != free:
            os.symlink(target, process.lock_path(did))
    with process.DomainLock() as lock:
        assert lock.domain_id == free
    assert target.read_bytes() == CONTENT
    with pytest.raises(SilError, match="no free ROS_DOMAIN_ID"):
        process.DomainLock(216)
    assert target.read_bytes() == CONTENT
    assert all(process.lock_path(d).is_symlink() for d in process.DOMAIN_RANGE if d != free)


def test_dangling_symlink_creates_nothing(lockdir, tmp_path):
    """A symlink to a file that does not exist yet: O_NOFOLLOW refuses it, nothing is created."""
    target = tmp_path / "would_be_created"
    os.symlink(target, process.lock_path(230))
    with pytest.raises(SilError):
        process.DomainLock(230)
    assert not target.exists()


def test_existing_lock_file_is_not_truncated(lockdir):
    """A regular lock file left by an earlier run is locked as it is (no O_TRUNC, nothing written)."""
    path = process.lock_path(225)
    path.write_bytes(CONTENT)
    with process.DomainLock(225) as lock:
        assert lock.domain_id == 225
        with pytest.raises(SilError):  # held: a second lock on the same id fails
            process.DomainLock(225)
    assert path.read_bytes() == CONTENT
    with process.DomainLock(225):  # released: free again
        pass


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to create a file owned by another user")
def test_other_users_lock_file_is_taken(lockdir):
    """A lock file owned by another uid (here nobody, 65534) is treated as taken, even by root
    (which could open it), and stays byte-identical."""
    path = process.lock_path(218)
    path.write_bytes(CONTENT)
    os.chown(path, 65534, 65534)
    with pytest.raises(SilError):
        process.DomainLock(218)
    assert path.read_bytes() == CONTENT and path.stat().st_uid == 65534
