"""``magtune fit-field``: fit a periodic design field b(t) to IGRF along the orbit (:mod:`..design.fitfield`)."""
from __future__ import annotations

import argparse
from datetime import datetime

from ..base.atomic import output_lock
from ..design import fitfield
from ..design.params import check_orbit
from .common import CommandError, add_force_argument, check_output, plain_summary, repo_path, say


def _parse_epoch(text: str) -> datetime:
    try:
        return datetime.fromisoformat(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an ISO date/time like 2026-03-20T00:00:00, got {text!r}") from None


def register(sub) -> None:
    p = sub.add_parser("fit-field", help="fit a periodic b(t) in orbital axes to IGRF along the orbit",
                              description=plain_summary(fitfield.__doc__))
    p.add_argument("--altitude", type=float, default=450.0, help="circular-orbit altitude [km] (default 450)")
    p.add_argument("--inclination", type=float, default=87.0, help="inclination [deg] (default 87)")
    p.add_argument("--harmonics", type=int, default=2, help="harmonics of the orbital rate (default 2)")
    p.add_argument("--days", type=float, default=3.0, help="days of orbit to average over (default 3)")
    p.add_argument("--step", type=float, default=20.0, help="sampling step [s] (default 20)")
    p.add_argument("--degree", type=int, default=10, help="IGRF degree/order (default 10, as in the paper)")
    p.add_argument("--raan", type=float, default=0.0, help="RAAN at epoch [deg] (default 0)")
    p.add_argument("--epoch", type=_parse_epoch, default=fitfield.DEFAULT_EPOCH, help="UTC epoch, ISO format (default 2026-03-20)")
    p.add_argument("--out", default=repo_path("config/field_model.yaml"),
                   help="output ROS 2 parameter file (default: config/field_model.yaml of the repository; an "
                        "existing file is kept unless --force)")
    add_force_argument(p)
    p.set_defaults(func=run)


def run(args) -> int:
    """Handler of ``magtune fit-field``: fit, print the report, write the file. Returns an exit code."""
    if args.harmonics < 1 or args.days <= 0 or args.step <= 0 or not 1 <= args.degree <= 13:
        raise CommandError("need --harmonics >= 1, --days > 0, --step > 0, 1 <= --degree <= 13", code=2)
    check_orbit(args.altitude * 1e3, args.inclination, "command line")
    check_output(args.out, force=args.force)
    with output_lock(args.out, "magtune fit-field", directory=False):  # one writer per output, for the whole run
        return _fit(args)


def _fit(args) -> int:
    """The fit, its report printed and the field model written to ``--out`` (locked)."""
    say("fit-field", f"sampling IGRF degree {args.degree} along {args.days:g} days of orbit every {args.step:g} s "
                     "and fitting (about a minute for the defaults)")
    field, report = fitfield.fit_field(args.altitude * 1e3, args.inclination, args.harmonics, args.days, args.step,
                              args.degree, args.epoch, args.raan)
    meta = dict(altitude=args.altitude * 1e3, inclination=args.inclination, igrf_degree=args.degree,
                days=args.days, step=args.step, raan=args.raan, epoch=args.epoch.isoformat())
    fitfield.write_field_model(args.out, field, report, meta)
    print(f"fit-field: {report.n_samples} IGRF-14 samples over {args.days:g} d, nodal period {field.period:.1f} s")
    print(report.markdown())
    print(f"wrote {args.out}")
    return 0
