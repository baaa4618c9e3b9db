"""The hold certificate (design/hold_certificate.py): what a scan of every admissible period and gain scale costs.

    python bench/bench_hold_certificate.py [--gains config/gains/sigma_120.yaml] [--full]

Prints, with the machine's load average (run it alone: 2 cores):

1. per sample period (N intervals per orbit), the 605 scales of the default grid (k = 1 .. 4.02,
   step 0.005) by one compiled product per scale (``SampledLoop.spectral_radius``, the tuner's
   arithmetic) against the certificate's polynomial blocks, as microseconds per interval and their
   ratio, with the largest difference in log rho;
2. with ``--full``, the whole certificate of the gains file over its design spec's range (the
   default spec, 1-30 s: 5,429 periods) on 1 and on 2 threads.

Timings are wall-clock; nothing is asserted.
"""
from __future__ import annotations

import argparse
import time

import numpy as np
from bench_tuner import load  # this directory's: the same load line

from magtune_core.design import hold_certificate as hc
from magtune_core.design.gains import load_gains
from magtune_core.design.model import AttitudeLTP
from magtune_core.design.params import load_spacecraft
from magtune_core.design.sampled import SampledLoop


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gains", default="config/gains/sigma_120.yaml")
    ap.add_argument("--spacecraft", default="config/spacecraft.yaml")
    ap.add_argument("--full", action="store_true", help="also the whole certificate on 1 and 2 threads")
    a = ap.parse_args()
    model = AttitudeLTP.from_params(load_spacecraft(a.spacecraft, warn=False))
    K = load_gains(a.gains).K
    ks = hc.scale_grid(4.0)
    print(f"{a.gains}: {len(ks)} scales, {load()}")
    hc.scan_products(np.eye(6), np.zeros((2, 6, 6)), ks)  # compile outside the timings
    print("| Ts [s] | N | one product per scale [us/interval] | polynomial blocks [us/interval] | ratio | max |dlog rho| |")
    print("|---|---|---|---|---|---|")
    for ts in (30.0, 10.0, 3.0, 1.0):
        loop = SampledLoop.build(model, ts)
        B = loop.Gamma @ K
        t = time.perf_counter()
        ref = loop.spectral_radius(ks[:, None, None] * K)
        t_ref = time.perf_counter() - t
        t = time.perf_counter()
        got = hc.scan_products(loop.Ad, B, ks)
        t_blk = time.perf_counter() - t
        n = loop.intervals
        print(f"| {ts:g} | {n} | {t_ref / n * 1e6:.1f} | {t_blk / n * 1e6:.1f} | {t_ref / t_blk:.1f}x | "
              f"{np.abs(np.log(got) - np.log(ref)).max():.1e} |")
    if a.full:
        for workers in (1, 2):
            cert = hc.certify_hold(model, K, 1.0, 30.0, 4.0, workers=workers)
            print(f"certificate 1-30 s on {workers} thread(s): {len(cert.periods)} periods, {cert.seconds:.1f} s, "
                  f"met {cert.met}, {cert.direct} periods by direct products; {load()}")


if __name__ == "__main__":
    main()
