"""``magtune campaign`` and ``magtune campaign-report``: Monte Carlo campaigns on Dask
(:mod:`..studies.campaign`, :mod:`..studies.campaign_report`)."""
from __future__ import annotations

import shutil
import sys
from pathlib import Path

from ..base.atomic import output_entries, output_lock
from ..base.errors import ConfigError
from ..base.paramfile import check_user_file
from ..studies import campaign, campaign_report, cluster
from .common import (
    CAMPAIGN_SCHEDULER_HELP,
    CommandError,
    add_oversubscribe_argument,
    add_scheduler_arguments,
    check_workers,
    plain_summary,
    scheduler_options,
)

#: What ``--force`` removes from an existing output directory (our own outputs only).
OUTPUTS = ("runs.parquet", "campaign.json", "spec.yaml", "summary.md", "envelopes.png", "histograms.png")


def register(sub) -> None:
    p = sub.add_parser("campaign", help="Monte Carlo campaign: dispersed runs, batched, on Dask; Parquet results",
                       description=plain_summary(campaign.__doc__))
    p.add_argument("spec", help="campaign spec (YAML: campaign, dispersions, criteria; see config/campaigns/)")
    p.add_argument("--runs", type=int, required=True, help="number of dispersed runs (per gains file)")
    p.add_argument("--out", required=True, help="output directory (must be empty or new, unless --force)")
    p.add_argument("--force", action="store_true", help="write into a non-empty --out (replaces earlier campaign outputs)")
    p.add_argument("--workers", type=int, default=None, help="LocalCluster worker processes (default: one per core)")
    add_oversubscribe_argument(p)
    p.add_argument("--dashboard", action="store_true",
                   help=f"serve the LocalCluster's Dask dashboard on {cluster.DASHBOARD_ADDRESS} (read-only, "
                        "unauthenticated; default: none)")
    add_scheduler_arguments(p, CAMPAIGN_SCHEDULER_HELP)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)
    r = sub.add_parser("campaign-report", help="report of a campaign directory: envelopes, histograms, summary.md",
                       description=plain_summary(campaign_report.__doc__))
    r.add_argument("dir", help="output directory of magtune campaign")
    r.set_defaults(func=run_report)


def _check_out_kind(out: Path) -> None:
    """--out is a directory or absent (checked before its lock is taken)."""
    if out.exists() and not out.is_dir():
        raise ConfigError(out, None, "--out exists and is not a directory; choose another --out")


def _check_out(out: Path, force: bool) -> None:
    """Under the lock: --out is empty (a lock file left by a killed run does not count), or
    ``force`` and the earlier campaign's own outputs are removed."""
    if output_entries(out):
        if not force:
            raise ConfigError(out, None, "--out is not empty; choose a new directory or add --force")
        for name in OUTPUTS:
            (out / name).unlink(missing_ok=True)
        if (out / "histories").is_dir():
            shutil.rmtree(out / "histories")


def _cluster_options(args):
    """(scheduler, TlsFiles or None) of the command line, checked before anything starts."""
    if args.dashboard and args.scheduler is not None:
        raise ConfigError("--dashboard", None, "only for the LocalCluster (an existing cluster serves its own)")
    return scheduler_options(args, "campaign", synchronous=True)


def run(args) -> int:
    if args.runs < 1:
        raise ConfigError("--runs", None, f"expected a positive number of runs, got {args.runs}")
    check_workers(args)
    sched, tls = _cluster_options(args)
    spec = campaign.load_spec(args.spec)  # ConfigError -> one line, exit 2, nothing started
    out = Path(args.out)
    _check_out_kind(out)
    with output_lock(out, "magtune campaign"):  # one writer per output, for the whole run
        _check_out(out, args.force)
        return _run(args, spec, out, sched, tls)


def _run(args, spec, out: Path, sched, tls) -> int:
    """The campaign into ``out`` (locked), its summary lines; exit status."""
    steps = spec.steps()
    print(f"campaign {spec.campaign['name']}: {args.runs} runs x {len(spec.gains_files)} gains file(s), "
          f"{spec.campaign['environment']} environment, {spec.campaign['orbits']:g} orbits ({steps} steps of "
          f"{spec.campaign['ts']:g} s), batches of {spec.campaign['batch_size']}, "
          f"scheduler {sched or 'LocalCluster (TLS)'}", flush=True)
    try:
        meta = campaign.run_campaign(spec, args.runs, out, scheduler=sched, workers=args.workers,
                                     progress=not args.no_progress, dashboard=args.dashboard, tls=tls)
    except OSError as exc:  # scheduler unreachable (distributed raises OSError subclasses on connect timeouts)
        raise CommandError(f"cannot reach the Dask scheduler {sched}: {exc}") from None
    cols = campaign.read_runs(out)
    print("\n".join(campaign_report.summary_lines(meta, cols)))
    print(f"wrote {out / 'runs.parquet'}, {out / 'histories'}/, {out / 'campaign.json'}; "
          f"report: magtune campaign-report {out}")
    failed = meta["failed_runs"]
    if failed:
        print(f"campaign: {len(failed)} of {meta['total_runs']} runs did not complete:", file=sys.stderr)
        for r in failed:
            print(f"  run {r['run']} ({r['gains']}): {r['error']}", file=sys.stderr)
        return 1
    return 0


def run_report(args) -> int:
    out = Path(args.dir)
    if not (out / "runs.parquet").is_file() or not (out / "campaign.json").is_file():
        raise ConfigError(out, None, "not a campaign directory (no runs.parquet / campaign.json); run magtune campaign first")
    check_user_file(out / "campaign.json", "written by magtune campaign")  # bounded before it is parsed
    with output_lock(out, "magtune campaign-report", option="DIR"):  # not while the campaign still writes it
        md = campaign_report.write_report(out)
    print(md)
    print(f"wrote {out / 'summary.md'}, {out / 'envelopes.png'}, {out / 'histograms.png'}")
    return 0
