"""SIL real-time factor: lockstep run of the three magtune_ros nodes over DDS at Ts = 1 s.

    python bench/sil_rtf.py [--orbits 5] [--gains FILE] [--environment paper|full]

Prints the real-time factor (simulated seconds / wall seconds of the stepping phase, i.e.
after discovery), the missed steps, and the largest deviation from the offline simulation.
Target (issue 3): >= 470x for 5 orbits with zero missed steps; with ``--environment full``
(J2 orbit, IGRF degree 10, drag, SRP; issue 5): >= 200x.
"""
import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from magtune_core.design.gains import load_gains, save_gains  # noqa: E402
from magtune_core.design.lq import lq_gains
from magtune_core.design.model import AttitudeLTP  # noqa: E402
from magtune_core.design.params import SpacecraftParams  # noqa: E402
from magtune_core.ros import sil  # noqa: E402
from magtune_core.sim.simulate import simulate  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--orbits", type=float, default=5.0)
    ap.add_argument("--gains", default=None, help="gains file (default: LQ sigma=60 test gain)")
    ap.add_argument("--no-check", action="store_true", help="skip the offline comparison")
    ap.add_argument("--environment", choices=("paper", "full"), default="paper")
    ap.add_argument("--no-visuals", action="store_true",
                    help="simulator without /tf and sim/markers (publish_tf/publish_markers false): their cost")
    a = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="magtune_bench_"))
    gains = a.gains
    if gains is None:
        gains = tmp / "sigma_60.yaml"
        save_gains(gains, lq_gains(AttitudeLTP.from_params(SpacecraftParams()), 60.0, 1.0))
    run = sil.run_sil(gains, orbits=a.orbits, ts=1.0, log_dir=tmp, environment=a.environment,
                      simulator_params=dict(publish_tf=False, publish_markers=False) if a.no_visuals else None)
    print(f"environment {a.environment}")
    print(run.summary())
    print(f"RTF {run.real_time_factor:.0f}x over {run.result.t[-1]:.0f} s sim "
          f"({len(run.result.t)} steps, {1e3 * run.wall_time / len(run.result.t):.3f} ms/step), "
          f"missed steps {run.counters.get('missed_steps')}")
    if not a.no_check:
        t0 = time.perf_counter()
        off = simulate(load_gains(gains).K, SpacecraftParams(), steps=len(run.result.t) - 1, ts=1.0,
                       environment=a.environment)
        dt = time.perf_counter() - t0
        err = max(np.max(np.abs(run.result.q - off.q)), np.max(np.abs(run.result.w - off.w)),
                  np.max(np.abs(run.result.m - off.m)))
        print(f"max |SIL - offline| = {err:.3g} (offline run {dt:.1f} s)")


if __name__ == "__main__":
    main()
