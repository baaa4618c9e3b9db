"""What a SIL run's bag recorded, as the node tests read it: the mode changes and a node's /diagnostics statuses."""
from __future__ import annotations

from magtune_core import bags as bag
from magtune_core.bags.decode import Decoder
from magtune_core.studies.report_modes import load_modes


def modes(bag_dir) -> list[tuple[float, str, str]]:
    """The mode changes of the bag: (t [s], mode, reason)."""
    return [(c.t, c.mode, c.reason) for c in load_modes(bag_dir)]


def statuses(bag_dir, node: str) -> list[tuple[int, str, dict]]:
    """Every /diagnostics status of ``magtune/<node>`` in the bag: (level, message, values)."""
    d = Decoder()
    out = []
    for m in bag.iter_messages(bag_dir, topics=["/diagnostics"]):
        for st in d.decode(m.data, m.type).status:
            if st.name == f"magtune/{node}":
                out.append((st.level, st.message, {kv.key: kv.value for kv in st.values}))
    return out
