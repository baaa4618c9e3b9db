"""``magtune sampling``: the sampling-period study, sigma x Ts grid (:mod:`..studies.sampling`)."""
from __future__ import annotations

import os
import sys
import time
from pathlib import Path

from ..base import jsonout
from ..base.ament import ROOT
from ..base.atomic import atomic_write, output_lock
from ..base.paramfile import read_user_text
from ..studies import sampling
from .common import (
    CommandError,
    add_environment_arguments,
    add_force_argument,
    add_oversubscribe_argument,
    check_outputs,
    check_workers,
    environment_options,
    plain_summary,
    positive_floats,
)


def register(sub) -> None:
    p = sub.add_parser("sampling", help="sampling-period study: sigma x Ts grid, table and plot in docs/",
                              description=plain_summary(sampling.__doc__))
    p.add_argument("--sigmas", type=positive_floats, default=list(sampling.DEFAULT_SIGMAS), help="default 60,120,240")
    p.add_argument("--ts", type=positive_floats, default=list(sampling.DEFAULT_TS), help="sample periods [s], default 1,2,5,10,20,30")
    p.add_argument("--orbits", type=float, default=5.0, help="run length [orbits] (default 5)")
    p.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1),
                   help="worker processes (default 2, or 1 on a one-core machine)")
    add_oversubscribe_argument(p)
    p.add_argument("--backend", choices=("offline", "sil"), default="offline",
                   help="offline simulate() (default) or the SIL nodes over DDS (identical trajectories, slower)")
    p.add_argument("--gains-dir", default=str(ROOT / "config" / "gains"),
                   help="holds sigma_<sigma>.yaml (default: config/gains of the repository)")
    p.add_argument("--spacecraft", default=str(ROOT / "config" / "spacecraft.yaml"),
                   help="spacecraft/orbit parameter file (default: config/spacecraft.yaml of the repository)")
    p.add_argument("--out-dir", default=str(ROOT / "docs"),
                   help="writes sampling.md/.png/.json here (default: docs/ of the repository; existing files "
                        "are kept unless --force)")
    add_force_argument(p)
    p.add_argument("--conclusion", default="", help="paragraph appended to the verdict (text, or @FILE)")
    add_environment_arguments(p, default="full")
    p.set_defaults(func=run)


def _progress(t0: float):
    def show(i, n, row):
        print(f"magtune sampling: run {i}/{n} done (sigma={row['sigma']:g}, Ts={row['ts']:g} s) "
              f"after {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    return show


def run(args) -> int:
    check_workers(args)
    opts = environment_options(args)
    conclusion_arg = args.conclusion if args.conclusion.startswith("@") else ("..." if args.conclusion else "")
    if args.conclusion.startswith("@"):
        args.conclusion = read_user_text(args.conclusion[1:]).strip()
    env_opts = dict(gravity_gradient=opts.gravity_gradient, drag=opts.drag, srp=opts.srp, field=opts.field,
                    igrf_degree=opts.igrf_degree)
    out = Path(args.out_dir)
    check_outputs(out, ("sampling.md", "sampling.png", "sampling.json"), force=args.force, option="--out-dir")
    with output_lock(out, "magtune sampling", option="--out-dir"):  # one writer per output, for the whole run
        return _study(args, out, env_opts, conclusion_arg)


def _study(args, out: Path, env_opts: dict, conclusion_arg: str) -> int:
    """The study's runs and its three files in ``out`` (locked); exit status."""
    t0 = time.perf_counter()
    try:
        rows = sampling.run_study(args.sigmas, args.ts, args.orbits, args.environment, env_opts, max(1, args.workers),
                                  args.gains_dir, args.spacecraft, args.backend, progress=_progress(t0))
    except FileNotFoundError as exc:  # missing gains file: one line
        raise CommandError(str(exc)) from None
    wall = time.perf_counter() - t0
    cmd = "magtune sampling " + " ".join(
        [f"--sigmas {','.join(f'{s:g}' for s in args.sigmas)}", f"--ts {','.join(f'{t:g}' for t in args.ts)}",
         f"--orbits {args.orbits:g}", f"--environment {args.environment}"]
        + ([f"--backend {args.backend}"] if args.backend != "offline" else [])
        + ([f"--conclusion {conclusion_arg}"] if conclusion_arg else []))
    meta = dict(command=cmd, wall=wall, workers=args.workers, environment=args.environment, orbits=args.orbits,
                conclusion=args.conclusion)
    md = sampling.write_markdown(rows, out / "sampling.md", meta)
    sampling.plot(rows, out / "sampling.png")
    atomic_write(out / "sampling.json", jsonout.dumps(dict(meta=meta, rows=[
        {k: v for k, v in r.items() if k not in ("t_plot", "dq_plot", "m_plot")} for r in rows]), indent=1))
    print(md)
    print(f"wrote {out / 'sampling.md'}, {out / 'sampling.png'}, {out / 'sampling.json'} in {wall:.0f} s")
    return 0
