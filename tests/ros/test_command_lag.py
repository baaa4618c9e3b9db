"""inputs.CommandLag: each sample with the command of one period before, whichever arrives first, in order."""
from __future__ import annotations

import pytest

from magtune_ros.inputs import CommandLag

pytestmark = pytest.mark.ros
T = 1_000_000_000  # one period [ns]


def test_sample_waits_for_its_command_and_leaves_in_order():
    lag = CommandLag(T, depth=2)
    assert lag.sample(0, "s0") == []              # no command of -1 s yet: waits
    assert lag.command(0, "c0") == []             # the command of 0 s is the next sample's
    assert lag.sample(T, "s1") == []              # s0 still waits (1 newer sample < depth)
    # depth newer samples: s0 leaves without a command (none came), then s1 with c0; s2 waits for c1
    assert lag.sample(2 * T, "s2") == [(0, "s0", None), (T, "s1", "c0")]
    assert not lag.missed(0) and lag.missed(T)    # 0 s had no earlier command to miss; 1 s did
    assert lag.sample(3 * T, "s3") == []
    assert lag.command(T, "c1") == [(2 * T, "s2", "c1")]
    assert lag.command(2 * T, "c2") == [(3 * T, "s3", "c2")]
    # the usual order: the command first, the sample then leaves at once
    assert lag.command(3 * T, "c3") == [] and lag.sample(4 * T, "s4") == [(4 * T, "s4", "c3")]
