"""``magtune front``: the J-optimal gain per sigma (:mod:`..studies.front`), or per level of one
requirement of the design spec (``--over ts_max|dipole_limit``, :mod:`..studies.requirement_front`):
J, c1, c2, table and plot."""
from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

from ..base import jsonout
from ..base.atomic import atomic_write, output_lock
from ..base.errors import ConfigError
from ..base.paramfile import read_user_text
from ..design.cmaes import CmaSettings
from ..design.gains import load_gains
from ..studies import front
from ..studies import requirement_front as rfront
from .common import (
    GAIN_MARGIN_HELP,
    START_SCALE_HELP,
    START_SCALES,
    TUNER_SCHEDULER_HELP,
    add_force_argument,
    add_oversubscribe_argument,
    add_scheduler_arguments,
    add_spec_argument,
    check_outputs,
    check_workers,
    cluster_executor,
    field_model_argument,
    hold_constraint,
    load_design_spec,
    load_model,
    plain_summary,
    positive_floats,
    repo_path,
    scheduler_options,
    shown_path,
)

OUTPUTS = ("front.md", "front.png", "front.json")
#: What ``--over`` may sweep: sigma (the paper's trade-off) or a requirement of the design spec.
OVER = ("sigma",) + tuple(rfront.AXES)
#: Reference gains of a requirement front: the paper-method gains (docs/table1.md).
REFERENCE_GLOB = "config/gains/paper_method/sigma_*.yaml"


def outputs(over: str) -> tuple:
    """The files a front over ``over`` writes (front.* for sigma, front_<axis>.* for a requirement)."""
    return OUTPUTS if over == "sigma" else tuple(n.replace("front.", f"front_{over}.") for n in OUTPUTS)


def register(sub) -> None:
    p = sub.add_parser("front", help="trade-off front: the J-optimal gain for each sigma, table and plot",
                       description=plain_summary(front.__doc__))
    p.add_argument("--over", choices=OVER, default="sigma",
                   help="what the front sweeps: sigma (the paper's trade-off, default), or one requirement of the "
                        "design spec (--spec) at --levels: ts_max (longest sample period of the hold margin [s]) "
                        "or dipole_limit (torquer limit per axis [A m^2]), for each of --sigmas")
    p.add_argument("--levels", type=positive_floats, default=None,
                   help="comma-separated levels of --over (default ts_max " +
                        ",".join(f"{v:g}" for v in rfront.DEFAULT_LEVELS["ts_max"]) + "; dipole_limit " +
                        ",".join(f"{v:g}" for v in rfront.DEFAULT_LEVELS["dipole_limit"]) + ")")
    p.add_argument("--sigmas", type=positive_floats, default=None,
                   help="comma-separated sigmas (default " + ",".join(str(s) for s in front.DEFAULT_SIGMAS) +
                        "; with --over a requirement: " + ",".join(str(s) for s in rfront.DEFAULT_SIGMAS) + ")")
    p.add_argument("--seed", type=int, default=0, help="random seed of every run (default 0)")
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                   help="processes evaluating each population (default: all cores)")
    add_oversubscribe_argument(p)
    p.add_argument("--max-evals", type=int, default=30000, help="evaluation budget per sigma (default 30000)")
    p.add_argument("--popsize", type=int, default=8, help="candidates per generation (default 8)")
    p.add_argument("--ts", type=float, default=None,
                   help="controller sample period of the hold constraint of a sigma front [s] (default 1)")
    p.add_argument("--gain-margin", type=float, default=None, help=GAIN_MARGIN_HELP + " (sigma front; default 2)")
    p.add_argument("--start-scale", choices=START_SCALES, default="feasible", help=START_SCALE_HELP)
    p.add_argument("--start", nargs="+", default=[], metavar="GAINS",
                   help="gains files tried as the start of every sigma besides the LQ gain and the previous sigma's "
                        "optimum (the lowest J at that sigma wins), e.g. config/gains/sigma_*.yaml; with --over a "
                        "requirement: the first start of the gains file's own sigma")
    p.add_argument("--reference", nargs="*", default=None, metavar="GAINS",
                   help="with --over a requirement: gains evaluated at every level beside the tuned ones (default "
                        + REFERENCE_GLOB + ", the paper-method gains)")
    add_spec_argument(p)
    p.add_argument("--out-dir", default=repo_path("docs"),
                   help="writes front.md/.png/.json (front_<over>.* with --over a requirement) here (default: "
                        "docs/ of the repository; existing files are kept unless --force)")
    add_scheduler_arguments(p, TUNER_SCHEDULER_HELP)
    p.add_argument("--resume", action="store_true",
                   help="with --over a requirement: keep the points of an interrupted run of the same front "
                        "(front_<over>.partial.json in --out-dir, written after every point) and tune the rest")
    add_force_argument(p)
    field_model_argument(p)
    p.set_defaults(func=run)


def run(args) -> int:
    """Handler of ``magtune front``: the front into ``--out-dir``, locked for the whole run (one writer
    per output). Returns an exit code."""
    with output_lock(args.out_dir, "magtune front", option="--out-dir"):
        return _run(args)


def _run(args) -> int:
    check_workers(args)
    for name in ("max_evals", "popsize"):
        if getattr(args, name) < 1:
            raise ConfigError("--" + name.replace("_", "-"), None, f"must be a positive integer, got {getattr(args, name)}")
    if args.over != "sigma":
        return run_requirement_front(args)
    if args.levels is not None or args.reference is not None or args.spec is not None:
        opt = "--levels" if args.levels is not None else ("--reference" if args.reference is not None else "--spec")
        raise ConfigError(opt, None, "applies to a requirement front only; add --over ts_max or --over dipole_limit")
    args.sigmas = args.sigmas or list(front.DEFAULT_SIGMAS)
    hold = hold_constraint(args)
    sched, tls = scheduler_options(args, "front")
    out = Path(args.out_dir)
    check_outputs(out, OUTPUTS, force=args.force, option="--out-dir")
    starts = [(f"{Path(f).name}", load_gains(f).K) for f in args.start]  # bad files: one line, exit 2, before any work
    model = load_model(args)
    settings = CmaSettings(popsize=args.popsize, max_evals=args.max_evals, workers=args.workers,
                           start_scale=args.start_scale)
    t0 = time.perf_counter()
    load0 = os.getloadavg()[0]

    def progress(i, n, pt):
        print(f"magtune front: sigma={pt.sigma:g} ({i}/{n}) J={pt.J:.3f} c1={pt.c1:.2f} c2={pt.c2:.1f} "
              f"in {pt.evaluations} evaluations, {pt.seconds:.0f} s", file=sys.stderr, flush=True)

    with cluster_executor(sched, tls) as executor:
        points = front.run_front(model, args.sigmas, settings, seed=args.seed, progress=progress, starts=starts,
                                 hold=hold, executor=executor)
    wall = time.perf_counter() - t0
    out.mkdir(parents=True, exist_ok=True)
    table = front.front_table(points)
    front.plot_front(points, out / "front.png")
    cmd = ("magtune front --sigmas " + ",".join(f"{s:g}" for s in args.sigmas) + f" --seed {args.seed} "
           f"--workers {args.workers} --max-evals {args.max_evals} --popsize {args.popsize} --start-scale {args.start_scale}"
           + (" --start " + " ".join(args.start) if args.start else ""))  # one option, nargs="+": a repeated one would replace it
    load = f"load average {load0:.1f} at the start, {os.getloadavg()[0]:.1f} at the end (2-core machine)"
    atomic_write(
        out / "front.md",
        "# Trade-off front (J-optimal gains per sigma)\n\n"
        f"Generated by `{cmd}` (field model {model.field.name}) in {wall:.0f} s, {load}.\n\n"
        "Each sigma is tuned by the converging tuner (`magtune tune`, CMA-ES, docs/tuning.md), "
        "started from the best (lowest J at that sigma) of the LQ gain, the previous sigma's gain and the "
        "`--start` gains; J, c1, c2, rho are recomputed at 128 Magnus steps or more (doubled until J is resolved "
        "to 1e-3). 'certified' = the stopping rule fired; 'no (budget)' = "
        "the evaluation budget ended the run first, so that J is an upper bound of the optimum; 'no (unresolved)' = "
        "the search found no improvement but the largest Magnus grid tried does not resolve J to the certificate's "
        "tolerance.\n\n"
        f"{table}\n\n![front](front.png)\n\nThe paper's Table 1 points (red squares) are plotted as published.\n")
    atomic_write(out / "front.json", jsonout.dumps({"command": cmd, "seconds": wall, "field_model": model.field.name,
                                                "points": [p.as_dict() for p in points]}, indent=1) + "\n")
    print(table)
    print(f"wrote {out / 'front.md'}, {out / 'front.png'}, {out / 'front.json'} ({wall:.0f} s)")
    return 0


def run_requirement_front(args) -> int:
    """``--over ts_max|dipole_limit``: the front over one requirement's levels (studies.requirement_front)."""
    for opt, val in (("--ts", args.ts), ("--gain-margin", args.gain_margin)):
        if val is not None:
            raise ConfigError(opt, None, "a requirement front takes the hold requirement from --spec, not " + opt)
    for name in ("workers", "max_evals", "popsize"):
        if getattr(args, name) < 1:
            raise ConfigError("--" + name.replace("_", "-"), None, f"must be a positive integer, got {getattr(args, name)}")
    axis = args.over
    sched, tls = scheduler_options(args, "front")
    levels = args.levels or list(rfront.DEFAULT_LEVELS[axis])
    sigmas = args.sigmas or list(rfront.DEFAULT_SIGMAS)
    out = Path(args.out_dir)
    names = outputs(axis)
    check_outputs(out, names, force=args.force, option="--out-dir")
    model = load_model(args)
    req = load_design_spec(args, model)
    if axis == "ts_max" and min(levels) < req.ts:
        raise ConfigError("--levels", None, f"ts_max levels must be >= the spec's ts_min ({req.ts:g} s)")
    starts, references = _start_and_reference_gains(args)
    settings = CmaSettings(popsize=args.popsize, max_evals=args.max_evals, start_scale=args.start_scale)
    t0, load0 = time.perf_counter(), os.getloadavg()[0]

    def progress(pt):
        what = f"infeasible ({pt.note})" if pt.K is None else (
            f"J={pt.J:.3f} c1={pt.c1:.2f} c2={pt.c2:.0f} margin={pt.hold_margin_min:.2f} "
            f"dipole={pt.dipole_peak:.1f} {'met' if pt.met else 'NOT met'}")
        extra = f" in {pt.evaluations} evaluations, {pt.seconds:.0f} s" if pt.label == "tuned" else ""
        print(f"magtune front: sigma={pt.sigma:g} {axis}={pt.level:g} [{pt.label}] {what}{extra}",
              file=sys.stderr, flush=True)

    partial = out / f"front_{axis}.partial.json"
    done = _resumed_points(partial) if args.resume else []
    kept = list(done)

    def record(pt):  # the partial record after every point: an interrupted front loses one point, not all
        kept.append(pt)
        out.mkdir(parents=True, exist_ok=True)
        atomic_write(partial, jsonout.dumps({"axis": axis, "points": [p.as_dict() for p in kept]}) + "\n")
        progress(pt)

    with cluster_executor(sched, tls) as executor:
        points = rfront.run_level_front(model, req, axis, levels, sigmas, settings=settings, seed=args.seed,
                                        workers=args.workers, starts=starts, references=references,
                                        progress=record, executor=executor, done=done)
    wall = time.perf_counter() - t0
    table = _write_level_front(args, out, points, model, req, wall, load0)
    partial.unlink(missing_ok=True)
    print(table)
    print(f"wrote {', '.join(str(out / n) for n in names)} ({wall:.0f} s)")
    return 0


def _start_and_reference_gains(args) -> tuple[dict, dict]:
    """``--start`` files as {sigma: K} and the reference gains (``--reference`` or the paper-method files)
    as {sigma: (label, K)}; a bad file: one line, exit 2, before any work."""
    starts = {}
    for f in args.start:
        g = load_gains(f)
        starts[float(g.sigma)] = g.K
    ref_files = args.reference if args.reference is not None else sorted(Path(repo_path(".")).glob(REFERENCE_GLOB))
    references = {}
    for f in ref_files:
        g = load_gains(f)
        references[float(g.sigma)] = (f"{Path(f).parent.name}/{Path(f).name}", g.K)
    return starts, references


def _resumed_points(partial: Path) -> list:
    """The points of an interrupted front's partial record (none if there is no record)."""
    if not partial.is_file():
        return []
    try:
        done = [rfront.LevelPoint.from_dict(d) for d in json.loads(read_user_text(partial))["points"]]
    except (ValueError, KeyError, TypeError) as exc:
        raise ConfigError(partial, None, f"not a partial front record ({exc}); remove it or drop --resume") from None
    print(f"magtune front: resuming with {len(done)} points of {partial}", file=sys.stderr)
    return done


def _write_level_front(args, out: Path, points, model, req, wall: float, load0: float) -> str:
    """The front's page, figure and JSON record in ``out``; returns the table printed."""
    axis, levels, sigmas, names = args.over, args.levels or list(rfront.DEFAULT_LEVELS[args.over]), \
        args.sigmas or list(rfront.DEFAULT_SIGMAS), outputs(args.over)
    out.mkdir(parents=True, exist_ok=True)
    table = rfront.level_table(points, axis)
    rfront.plot_level_front(points, axis, out / names[1])
    cmd = (f"magtune front --over {axis} --levels " + ",".join(f"{v:g}" for v in levels) + " --sigmas "
           + ",".join(f"{s:g}" for s in sigmas) + f" --seed {args.seed} --workers {args.workers} --max-evals "
           f"{args.max_evals} --popsize {args.popsize}" + (f" --spec {args.spec}" if args.spec else "")
           + (" --start " + " ".join(args.start) if args.start else ""))
    load = f"load average {load0:.1f} at the start, {os.getloadavg()[0]:.1f} at the end (2-core machine)"
    unit = rfront.AXES[axis]
    atomic_write(
        out / names[0],
        f"# Requirement front: J against {axis}\n\n"
        f"Generated by `{cmd}` (field model {model.field.name}) in {wall:.0f} s, {load}.\n\n"
        f"Design spec: {shown_path(req.source)} ({req.describe()}); each row moves {axis} to the level [{unit}] and keeps the "
        "rest. 'tuned' = the certified optimum of J under that level's hard requirements (`magtune tune --spec`, "
        "continuation from the hardest level); the reference rows are the paper-method gains evaluated at that "
        "level (their J does not depend on it; 'met' says whether they meet the level's requirements). "
        "'hold margin (min)' is the smallest hold gain margin of the dense scan over the level's sample-period "
        "range, 'peak dipole' the linear worst case of the budget (docs/requirements.md).\n\n"
        f"{table}\n\n![front]({names[1]})\n")
    atomic_write(out / names[2], jsonout.dumps({"command": cmd, "seconds": wall, "field_model": model.field.name,
                                               "axis": axis, "spec": req.describe(),
                                               "points": [p.as_dict() for p in points]}, indent=1) + "\n")
    return table
