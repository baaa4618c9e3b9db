"""``magtune verify GAINS``: Monte Carlo verification against the design spec's pointing
requirements (:mod:`..studies.verify`). Exit 0: every requirement passes; 3: a requirement
fails; 1: a run did not complete; 2: bad input."""
from __future__ import annotations

import json
from contextlib import ExitStack
from pathlib import Path

from ..base.atomic import atomic_write, output_entries, output_lock
from ..base.errors import ConfigError
from ..studies import verify
from .common import (
    CAMPAIGN_SCHEDULER_HELP,
    CommandError,
    add_oversubscribe_argument,
    add_scheduler_arguments,
    add_spec_argument,
    check_workers,
    load_design_spacecraft,
    load_design_spec,
    load_model,
    plain_summary,
    repo_path,
    scheduler_options,
    shown_path,
)

OUTPUTS = ("verify.md", "verify.json")


def register(sub) -> None:
    p = sub.add_parser("verify", help="Monte Carlo verification of gains against the design spec (exit 0 pass, 3 fail)",
                       description=plain_summary(verify.__doc__))
    p.add_argument("gains", help="gains file (config/gains/sigma_*.yaml)")
    add_spec_argument(p)
    p.add_argument("--campaign", metavar="CAMPAIGN_SPEC", default=None,
                   help="dispersions and environment (default config/campaigns/example.yaml of the repository, from "
                        "any working directory); its gains, ts and "
                        "criteria are replaced by GAINS, the verified periods and the design spec's requirements")
    p.add_argument("--runs", type=int, default=200, help="dispersed runs per sample period (default 200)")
    p.add_argument("--also-ts", metavar="TS", default="",
                   help="comma-separated sample periods [s] flown too, e.g. the flight computer's own (in the "
                        "design spec's range)")
    p.add_argument("--out", required=True, help="report directory (new or empty, unless --force)")
    p.add_argument("--force", action="store_true", help="write into a non-empty --out")
    p.add_argument("--record", action="store_true",
                   help="also write the verdict into GAINS' provenance (key 'verification'; atomic)")
    p.add_argument("--workers", type=int, default=None, help="LocalCluster worker processes (default: one per core)")
    add_oversubscribe_argument(p)
    add_scheduler_arguments(p, CAMPAIGN_SCHEDULER_HELP)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _check(args):
    """Every option checked before any run (one line naming it, exit 2); returns (scheduler, TlsFiles or None)."""
    if args.runs < 1:
        raise ConfigError("--runs", None, f"expected a positive number of runs, got {args.runs}")
    check_workers(args)
    try:
        args.also_ts = [float(t) for t in args.also_ts.split(",") if t.strip()]
    except ValueError:
        raise ConfigError("--also-ts", None, f"expected comma-separated periods in seconds, got {args.also_ts!r}") from None
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ConfigError(out, None, "--out exists and is not an empty directory; choose a new one or add --force")
    return scheduler_options(args, "verify", synchronous=True)


def _check_empty(out: Path, force: bool) -> None:
    """Under the lock: --out is empty (a lock file left by a killed run does not count) unless ``force``."""
    if output_entries(out) and not force:
        raise ConfigError(out, None, "--out exists and is not an empty directory; choose a new one or add --force")


def run(args) -> int:
    sched, tls = _check(args)
    with ExitStack() as held:  # one writer per output, for the whole run: --out, and GAINS with --record
        held.enter_context(output_lock(args.out, "magtune verify"))
        if args.record:
            held.enter_context(output_lock(args.gains, "magtune verify --record", directory=False, option="GAINS"))
        _check_empty(Path(args.out), args.force)
        return _verify(args, sched, tls)


def _verify(args, sched, tls) -> int:
    """The verification into ``--out`` (locked): inputs, runs, verify.md/json; exit status."""
    from ..design.gains import load_gains

    gains = load_gains(args.gains)  # ConfigError -> one line, exit 2, before any run
    req = load_design_spec(args)
    p = load_design_spacecraft(args)
    # the default is the repository's file from any working directory; files record its relative name
    campaign_file = args.campaign or repo_path("config/campaigns/example.yaml")
    campaign = args.campaign or shown_path(campaign_file)
    verify.load_spec(campaign_file)  # validated before any worker starts
    lo, hi = req.sampling["ts_min"], req.sampling["ts_max"]
    bad = [t for t in args.also_ts if not lo <= t <= hi]
    if bad:
        raise ConfigError("--also-ts", None, f"{bad[0]:g} s lies outside the design spec's range {lo:g}-{hi:g} s; "
                          "widen sampling.ts_min/ts_max or drop it")
    tightest = gains.provenance.get("hold_tightest_ts")
    if tightest is None and req.gain_margin:
        from ..design.requirements import tightest_period

        tightest = tightest_period(load_model(args), gains.K, req)
    periods = verify.verify_periods(req, tightest, args.also_ts)
    print(f"verify {args.gains}: {args.runs} runs at Ts = {', '.join(f'{t:g}' for t in periods)} s "
          f"(ends of {lo:g}-{hi:g} s and the tightest hold margin" + (", asked" if args.also_ts else "") + "), "
          f"dispersions of {campaign} with the design spec's rates, residual dipoles and torquers "
          f"({req.dipole_budget or req.dipole_limit:g}-{req.dipole_limit:g} A m^2)"
          + (f"; sensor noise and torquer range of the hardware file {args.hardware}" if args.hardware else ""), flush=True)
    try:
        res = verify.run_verify(args.gains, req, campaign_file, args.runs, args.out, tightest=tightest, p=p,
                                scheduler=sched, workers=args.workers, progress=not args.no_progress, tls=tls,
                                extra_periods=args.also_ts)
    except OSError as exc:
        raise CommandError(f"cannot reach the Dask scheduler {args.scheduler}: {exc}") from None
    res["campaign"] = campaign  # as given, or the default's name in the repository (no checkout path)
    md = verify.table(res)
    verdict = "PASS" if res["passed"] else ("FAIL (runs did not complete)" if res["failed_runs"] else "FAIL")
    text = f"# verify {args.gains}\n\n{md}\n\n{verdict}: {res['runs']} runs per period, {res['seconds']:.0f} s\n"
    out = Path(args.out)
    atomic_write(out / "verify.md", text)
    atomic_write(out / "verify.json", json.dumps(verify.summary(res), indent=1))
    print(md)
    print(f"{verdict} ({res['seconds']:.0f} s); wrote {out / 'verify.md'}")
    if args.record:
        _record(args.gains, verify.summary(res))
    if res["failed_runs"]:
        return verify.RUN_FAILED
    return verify.PASSED if res["passed"] else verify.REQUIREMENT_FAILED


def _record(path, record: dict) -> None:
    """The verdict into the gains file's provenance, the file's header kept (written atomically)."""
    from ..design.gains import update_provenance

    update_provenance(path, {"verification": record})
    print(f"recorded the verdict in {path}")
