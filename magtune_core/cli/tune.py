"""``magtune tune``: H-infinity tuning of K for one sigma: CMA-ES to a certified optimum (default)
or the paper's randomized algorithm (``--method paper``, paper 4.2, eqs. 23-25)."""
from __future__ import annotations

import os
import signal
import sys

from ..base.atomic import output_lock
from ..base.errors import ConfigError
from ..design.cmaes import CmaSettings
from ..design.gains import load_gains, save_gains
from ..design.pipeline import METHODS, InfeasibleStart, requirement_lines, tune_gains, tune_robust_gains
from ..design.tuner import TunerSettings
from ..onboard.params import TS_DEFAULT
from .common import (
    GAIN_MARGIN_HELP,
    START_SCALE_HELP,
    START_SCALES,
    TUNER_SCHEDULER_HELP,
    CommandError,
    add_force_argument,
    add_oversubscribe_argument,
    add_scheduler_arguments,
    add_spec_argument,
    check_output,
    check_workers,
    cluster_executor,
    field_model_argument,
    hold_constraint,
    load_design_spacecraft,
    load_design_spec,
    load_model,
    repo_path,
    scheduler_options,
)


def register(sub) -> None:
    t = sub.add_parser("tune", help="H-inf tuning of K for one sigma (CMA-ES to the optimum, or the paper's 4.2)")
    t.add_argument("--sigma", type=float, required=True, help="control-effort weight of z = [Z x; sigma K x]")
    t.add_argument("--method", choices=METHODS, default="cma",
                   help="cma (default): CMA-ES with batched populations, local restarts and a certified stop "
                        "(docs/tuning.md); paper: the randomized algorithm of paper 4.2 as published")
    t.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    t.add_argument("--start", metavar="GAINS", default=None,
                   help="start from this gains file (default: the LQ gain of the averaged model, paper 4.2)")
    t.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                   help="processes evaluating candidates (default: all cores)")
    add_oversubscribe_argument(t)
    c = t.add_argument_group("cma method")
    c.add_argument("--popsize", type=int, default=8, help="candidates per generation (default 8)")
    c.add_argument("--max-evals", type=int, default=30000, help="evaluation budget (default 30000)")
    c.add_argument("--restarts", type=int, default=2,
                   help="consecutive non-improving local restarts that certify convergence (default 2)")
    add_spec_argument(c)
    c.add_argument("--gain-margin", type=float, default=None, help=GAIN_MARGIN_HELP)
    c.add_argument("--start-scale", choices=START_SCALES, default="feasible", help=START_SCALE_HELP)
    add_scheduler_arguments(c, TUNER_SCHEDULER_HELP)
    p = t.add_argument_group("paper method")
    p.add_argument("--samples", type=int, default=540, help="candidates per iteration N (paper: 540)")
    p.add_argument("--r-max", type=float, default=0.995, help="stop when the rejection ratio reaches this")
    p.add_argument("--mu", type=float, default=1e-3, help="initial step size")
    p.add_argument("--max-iter", type=int, default=300, help="iteration limit (default 300)")
    p.add_argument("--patience", type=int, default=1,
                   help="stop at the P-th consecutive iteration with r >= r_max (1 = the paper's rule)")
    t.add_argument("--ts", type=float, default=None,
                   help="controller sampling period written to the file [s] (default: the design spec's ts_min; "
                        "given, the hold constraint is asked at this period only; refused with --spec, whose "
                        "ts_min..ts_max own the sample periods)")
    t.add_argument("--robust", metavar="SPEC", default=None,
                   help="robust tuning: minimize the worst J over the model set of this robust spec "
                        "(magtune_core/design/robust.py; CMA-ES tuner)")
    field_model_argument(t)
    t.add_argument("--out", help="gains file to write (default config/gains/sigma_<sigma>.yaml of the "
                                 "repository; an existing file is kept unless --force)")
    add_force_argument(t)
    t.add_argument("--verify-runs", type=int, default=24,
                   help="runs per period of the closing Monte Carlo check under a design spec, written into the "
                        "file's provenance (default 24; 0: none; the full check is magtune verify)")
    t.add_argument("--quiet", action="store_true", help="no progress bar")
    t.set_defaults(func=run)


#: Options that only one method reads, with their defaults: given to the other method they would be
#: silently ignored (a paper-style ``--samples 200 --max-iter 6`` does not shorten a CMA-ES run).
METHOD_ONLY = {"cma": {"popsize": 8, "max_evals": 30000, "restarts": 2, "gain_margin": None, "start_scale": "feasible",
                       "spec": None, "scheduler": None, "tls_ca_file": None, "tls_cert": None, "tls_key": None},
               "paper": {"samples": 540, "r_max": 0.995, "mu": 1e-3, "max_iter": 300, "patience": 1}}


def _check_args(args):
    """Every option checked before any work (one line naming it, exit 2); returns the cluster's
    (scheduler, TlsFiles or None) of ``--scheduler``."""
    for method, options in METHOD_ONLY.items():
        if args.method != method:
            for name, default in options.items():
                if getattr(args, name) != default:
                    raise ConfigError("--" + name.replace("_", "-"), None,
                                      f"is an option of --method {method}; add --method {method} or drop it")
    if args.verify_runs < 0:
        raise ConfigError("--verify-runs", None, f"must be 0 (none) or a positive number of runs, got {args.verify_runs}")
    check_workers(args)
    for name in ("popsize", "max_evals", "restarts", "samples", "max_iter", "patience"):
        if getattr(args, name) < 1:
            raise ConfigError("--" + name.replace("_", "-"), None, f"must be a positive integer, got {getattr(args, name)}")
    if not args.sigma > 0:
        raise ConfigError("--sigma", None, f"must be positive, got {args.sigma:g}")
    if args.spec is not None and args.ts is not None:
        raise ConfigError("--ts", None, f"the design spec {args.spec} owns the sample periods (ts_min, ts_max); "
                                        "drop --ts, or drop --spec for a tune held at --ts alone")
    hold_constraint(args)
    return scheduler_options(args, "tune")


def requirements_of(args):
    """The design spec the CMA-ES tuner is asked to meet: None for the paper method, for
    ``--gain-margin 0`` (the paper's unconstrained problem) and for a single-period constraint
    (``--ts`` / ``--gain-margin`` given); otherwise ``--spec`` or config/design.yaml."""
    if args.method != "cma" or args.gain_margin == 0 or (args.spec is None and (args.ts is not None
                                                                                or args.gain_margin is not None)):
        return None
    return load_design_spec(args)


def run(args) -> int:
    sched, tls = _check_args(args)
    out = check_output(args.out or repo_path(f"config/gains/sigma_{args.sigma:g}.yaml"), force=args.force)
    model = load_model(args)
    req = requirements_of(args)
    start_K = load_gains(args.start).K if args.start else None  # a bad file: one line, exit 2, before any work
    with output_lock(out, "magtune tune", directory=False), \
            cluster_executor(sched, tls) as executor:  # one writer of the gains file; on --scheduler: connected
        if args.robust:
            return _run_robust(args, model, out, start_K, executor)
        return _tune(args, model, out, req, start_K, executor)


def _tune(args, model, out, req, start_K, executor) -> int:
    """``tune`` without --robust: the search, its closing verification, the file, the summary lines."""
    from tqdm import tqdm

    bar = tqdm(desc=f"tune sigma={args.sigma:g} ({args.method})", unit="gen" if args.method == "cma" else "it",
               disable=args.quiet, file=sys.stderr)
    stop = _StopRequest()

    def progress(*a):
        bar.update(1)
        if args.method == "paper":
            it, J, r, mu, nb = a
            bar.set_postfix_str(f"J={J:.3f} r={r:.4f} mu={mu:.2e} better={nb}")
            return
        ev, J, gen, step, restart = a
        bar.set_postfix_str(f"J={J:.4f} evals={ev} step={step:.2e} restart={restart}")
        if stop.requested:  # raised here, between generations, never inside compiled code
            raise KeyboardInterrupt

    try:
        with stop if args.method == "cma" else _NoStop():
            res = tune_gains(model, args.sigma, method=args.method, seed=args.seed, start_K=start_K,
                             start_name=args.start, workers=args.workers, ts=TS_DEFAULT if args.ts is None else args.ts,
                             gain_margin=2.0 if args.gain_margin is None else args.gain_margin,
                             cma=_cma_settings(args), requirements=req, executor=executor,
                             paper=TunerSettings(samples=args.samples, r_max=args.r_max, mu=args.mu,
                                                 max_iter=args.max_iter, patience=args.patience),
                             progress=progress)
    except InfeasibleStart as exc:  # one line, exit 2, before the search
        raise ConfigError("--start" if args.start else ("--spec" if req is not None else "--gain-margin"), None,
                          f"{exc}" if req is not None else f"{exc}; try a smaller --gain-margin or a longer --ts") from None
    except ValueError as exc:
        raise CommandError(f"{exc}") from None
    finally:
        bar.close()
    for note in res.notes:
        print(f"tune: {note}")
    if args.method == "paper":
        header = f"magtune tune --method paper --sigma {args.sigma:g} --seed {args.seed} --samples {args.samples}"
    elif req is not None:
        header = (f"magtune tune --sigma {args.sigma:g} --seed {args.seed} --spec {args.spec or 'config/design.yaml'}"
                  f" ({req.describe()})" + (f" --start {args.start}" if args.start else ""))
    else:
        header = (f"magtune tune --sigma {args.sigma:g} --seed {args.seed} --ts {res.gains.ts:g} --gain-margin "
                  f"{2.0 if args.gain_margin is None else args.gain_margin:g}" + (f" --start {args.start}" if args.start else ""))
    if req is not None and args.verify_runs > 0 and not res.interrupted:
        res.gains.provenance["verification"] = _closing_verification(args, res.gains, req)
    save_gains(out, res.gains, header=header)
    g, r = res.gains.provenance, res.result
    print(f"sigma={args.sigma:g} [{r.method}]  J: {r.J0:.3f} ({res.start}, {res.steps} Magnus steps) -> {g['J']:.3f} in "
          f"{r.evaluations} evaluations, {r.seconds:.1f} s, {res.state}; c1={g['c1']:.3f} c2={g['c2']:.2f} "
          f"rho={g['rho']:.5f} ({res.analysis_steps} steps); wrote {out}")
    if req is not None:
        print(f"requirements ({req.describe()}): {'met' if g['requirements_met'] else 'NOT met'}")
        for line in requirement_lines(g, req.gain_margin):
            print(f"  {line}")
    return 130 if res.interrupted else 0


def _closing_verification(args, gains, req) -> dict:
    """A short Monte Carlo (``--verify-runs`` per period, in this process) of the new gain against
    the design spec (studies.verify): its summary for the provenance, one line printed."""
    import tempfile

    from ..design.gains import save_gains
    from ..studies import verify

    with tempfile.TemporaryDirectory(prefix="magtune_tune_verify_") as tmp:
        path = f"{tmp}/gains.yaml"
        save_gains(path, gains)
        res = verify.run_verify(path, req, repo_path("config/campaigns/example.yaml"), args.verify_runs, f"{tmp}/mc",
                                tightest=gains.provenance.get("hold_tightest_ts"), p=load_design_spacecraft(args),
                                scheduler="synchronous")
    summary = verify.summary(res)
    summary["campaign"] = "config/campaigns/example.yaml"
    failing = sorted({f"{r.name} at Ts = {r.ts:g} s" for r in res["rows"] if not r.ok})
    print(f"verification ({args.verify_runs} runs per period, Ts = {', '.join(f'{t:g}' for t in res['periods'])} s, "
          f"{res['seconds']:.0f} s): " + ("pass" if res["passed"] else "FAIL: " + "; ".join(failing))
          + "; the full check: magtune verify")
    return summary


def _cma_settings(args) -> CmaSettings:
    """The CMA-ES options of the command line (workers and Magnus steps are the pipeline's)."""
    return CmaSettings(popsize=args.popsize, max_evals=args.max_evals, certify=args.restarts, start_scale=args.start_scale)


class _NoStop:
    """The paper method has no stop request: Ctrl-C interrupts at once."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


class _StopRequest:
    """While active, SIGTERM and the first Ctrl-C only request a stop, which the tuner's progress
    callback turns into KeyboardInterrupt after the current generation: the search ends and the
    best gain so far is written (``stop: interrupted``). Raising from the signal handler itself
    would land inside compiled (numba) code, where it surfaces as a SystemError and loses the
    run. A second Ctrl-C interrupts at once."""

    def __init__(self):
        self.requested = False
        self._previous = {}

    def _handler(self, signum, frame):
        if self.requested and signum == signal.SIGINT:
            raise KeyboardInterrupt
        self.requested = True
        print("\nmagtune tune: stop requested; finishing the current generation and writing the best gain so far",
              file=sys.stderr, flush=True)

    def __enter__(self):
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._previous[sig] = signal.signal(sig, self._handler)
        return self

    def __exit__(self, *exc):
        for sig, h in self._previous.items():
            signal.signal(sig, h)


def _run_robust(args, model, out, start_K=None, executor=None) -> int:
    """``tune --robust SPEC``: worst-case J over the spec's model set (design.pipeline.tune_robust_gains)."""
    from ..design.robust import load_robust_spec, model_set

    skipped: list = []
    models = model_set(model, load_robust_spec(args.robust), args.robust, skipped=skipped)
    hold_constraint(args)
    try:
        res = tune_robust_gains(model, models, args.sigma, seed=args.seed,
                                start_K=start_K, start_name=args.start,
                                workers=args.workers, ts=TS_DEFAULT if args.ts is None else args.ts,
                                gain_margin=2.0 if args.gain_margin is None else args.gain_margin,
                                cma=_cma_settings(args), spec_name=args.robust, requirements=requirements_of(args),
                                executor=executor)
    except ImportError:
        raise CommandError("--robust needs the CMA-ES tuner (magtune_core.design.cmaes), not installed here") from None
    except ValueError as exc:
        raise CommandError(f"{exc}; try a larger --sigma") from None
    save_gains(out, res.gains, header=f"magtune tune --sigma {args.sigma:g} --seed {args.seed} --robust {args.robust}")
    g, rf = res.gains.provenance, res.robust
    print(f"sigma={args.sigma:g} robust over {len(models)} models: worst J {res.result.J0:.3f} (start) -> "
          f"{g['worst_J']:.3f} ({rf.worst_name}); nominal J {g.get('J', float('nan')):.3f}; {res.result.seconds:.1f} s; "
          f"wrote {out}")
    return 0
