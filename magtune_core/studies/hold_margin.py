"""The hold margin against the sample period: a gain's first unstable scale at every admissible
period (``magtune analyze --requirements --margin-plot``, the picture in docs/requirements.md)."""
from __future__ import annotations

import numpy as np

from ..base.atomic import atomic_savefig
from ..design.hold_certificate import HoldCertificate


def margin_figure(cert: HoldCertificate, path, required: float, guard: float, title: str = "") -> None:
    """Plot the first unstable scale of the held loop per admissible period, the required margin and
    its guard band, and where the grid found nothing unstable (above its top).

    Parameters
    ----------
    cert : HoldCertificate
        A certificate (:func:`magtune_core.design.hold_certificate.certify_hold`), usually over a grid
        reaching above the required margin so the curve shows where stability ends.
    path : str or Path
        PNG written (atomically).
    required : float
        The design spec's gain margin (drawn as a line).
    guard : float
        Its relative guard band (drawn as a band above it).
    title : str
        Figure title.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.2))
    ts, first = cert.periods, cert.first_unstable
    found = np.isfinite(first)
    ax.plot(ts[found], first[found], ".", ms=2, color="C3", label="first unstable scale k (grid)")
    ax.plot(ts[~found], np.full((~found).sum(), cert.top), ".", ms=1, color="C2",
            label=f"stable on the whole grid (up to {cert.top:g})")
    ax.axhline(required, color="k", lw=1, label=f"required margin {required:g}")
    ax.axhspan(required, required * (1 + guard), color="0.7", label=f"guard band {guard:.1%}")
    ax.set_xscale("log")
    ax.set_xlabel("sample period T / N [s]")
    ax.set_ylabel("gain scale k (held loop with k K)")
    ax.set_ylim(1.0, cert.top * 1.02)
    ax.set_title(title or f"held-loop margin, {len(ts)} admissible periods, k step {cert.step:g}")
    ax.legend(loc="lower left", fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    atomic_savefig(fig, path, dpi=110)
    plt.close(fig)
