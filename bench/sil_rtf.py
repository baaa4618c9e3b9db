"""SIL real-time factor: lockstep run of the three magtune_ros nodes over DDS at Ts = 1 s.

    python bench/sil_rtf.py [--orbits 5] [--gains FILE] [--environment paper|full]
    python bench/sil_rtf.py --compare modes|estimator|stack [--orbits 5] [--environment full] [--repeat 3]

Prints the real-time factor (simulated seconds / wall seconds of the stepping phase, i.e.
after discovery), the missed steps, and the largest deviation from the offline simulation.
Target (issue 3): >= 470x for 5 orbits with zero missed steps; with ``--environment full``
(J2 orbit, IGRF degree 10, drag, SRP; issue 5): >= 200x. ``--compare`` flies the same run twice,
side by side in one invocation: without and with the mode manager (started in POINTING, so both
fly the same law; target: within 10 %), or with truth feedback and with the attitude estimator
(target: >= 70 %), or with truth feedback and the full stack (``stack``: the mode manager managing sensors,
estimator and controller, started in POINTING so both fly eq. 17 from the start; issue 44's target: the
stack >= 250x), and prints the ratio and the machine load (/proc/loadavg) of each run.
``--repeat N`` alternates the pair N times (baseline, variant, baseline, ...) and prints the
median of the N ratios: on a shared machine one pair is noisy (the same run varied 700-1100x).
"""
import argparse
import resource
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
    ap.add_argument("--compare", choices=tuple(VARIANTS), default=None,
                    help="the same run without and with the mode manager / the attitude estimator")
    ap.add_argument("--repeat", type=int, default=1, help="--compare: alternate the pair this many times")
    a = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="magtune_bench_"))
    if a.compare:
        return compare(a, tmp)
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


#: --compare choice -> ((baseline name, variant name), the variant's run_sil keywords)
VARIANTS = {"modes": (("without mode manager", "with mode manager"), dict(modes=True, initial_mode="POINTING")),
            "estimator": (("truth feedback", "estimator"), dict(attitude="estimator")),
            "stack": (("truth feedback", "full stack"), dict(modes=True, initial_mode="POINTING", attitude="estimator"))}


def compare(a, tmp: Path) -> None:
    """Baseline and variant, alternated ``--repeat`` times after a warm-up run, in this invocation; RTF ratios."""
    gains = a.gains or str(Path(__file__).resolve().parents[1] / "config" / "gains" / "sigma_120.yaml")
    names, variant = VARIANTS[a.compare]
    print(f"load before: {_load()}; {a.orbits:g} orbits, environment {a.environment}, gains {gains}")
    sil.run_sil(gains, orbits=0.1, ts=1.0, log_dir=tmp / "warm", environment=a.environment)  # caches, discovery
    ratios = []
    for i in range(a.repeat):
        rtf = []
        for name, extra in zip(names, ({}, variant)):
            cpu0 = _children_cpu()
            run = sil.run_sil(gains, orbits=a.orbits, ts=1.0, log_dir=tmp / f"{name.replace(' ', '_')}_{i}",
                              environment=a.environment, **extra)
            rtf.append(run.real_time_factor)
            steps = len(run.result.t)
            print(f"{name:22s} RTF {run.real_time_factor:6.0f}x  missed steps {run.counters.get('missed_steps')}  "
                  f"wall {run.wall_time:.1f} s  {1e3 * run.wall_time / steps:.3f} ms/step  node CPU "
                  f"{1e3 * (_children_cpu() - cpu0) / steps:.3f} ms/step  load {_load()}")
        ratios.append(rtf[1] / rtf[0])
        print(f"ratio {names[1]} / {names[0]}: {ratios[-1]:.3f}")
    if a.repeat > 1:
        print(f"median ratio of {a.repeat}: {float(np.median(ratios)):.3f} (min {min(ratios):.3f}, max {max(ratios):.3f})")


def _children_cpu() -> float:
    """CPU seconds (user + system) of this process's finished children: the node processes of the runs so
    far (start-up and shutdown included), so a run's difference over its steps is its nodes' CPU per step."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _load() -> str:
    """The 1-, 5- and 15-minute load averages."""
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


if __name__ == "__main__":
    main()
