"""The mode band of ``magtune report`` (magtune_core.studies.report_modes) on scripted mode changes;
the band from a real SIL bag: tests/ros/test_faults_modes_sil.py."""
import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402

from magtune_core.studies import report_modes as rm  # noqa: E402

CHANGES = [rm.ModeChange(0.0, "POINTING", "POINTING", "start"), rm.ModeChange(103.0, "SAFE", "POINTING", "stale"),
           rm.ModeChange(140.0, "DETUMBLE", "SAFE", "fresh")]


def test_spans_and_bands_clip_to_the_window():
    assert rm.spans(CHANGES, 160.0) == [(0.0, 103.0, "POINTING"), (103.0, 140.0, "SAFE"), (140.0, 160.0, "DETUMBLE")]
    fig, ax = plt.subplots()
    drawn = rm.draw_bands(ax, rm.spans(CHANGES, 160.0), 100.0, 50.0, 150.0)
    assert drawn == [(0.5, 1.03, "POINTING", "tab:green"), (1.03, 1.4, "SAFE", "tab:red"),
                     (1.4, 1.5, "DETUMBLE", "tab:orange")]
    assert len(ax.patches) == 3 and ax.get_legend_handles_labels()[1] == ["mode POINTING", "mode SAFE", "mode DETUMBLE"]
    plt.close(fig)


def test_text_lists_the_transitions():
    s = {"bag": {"modes": rm.summary_entry(CHANGES, 160.0)}, "other": {}}
    md = "\n".join(rm.markdown(s))
    assert "bag: starts in POINTING; 2 transition(s)." in md and "| 103.0 | POINTING | SAFE | stale |" in md
    assert "other" not in md and rm.markdown({"other": {}}) == []
    assert "<td>SAFE</td>" in rm.html_section(s)
