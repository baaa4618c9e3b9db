"""``magtune fit-field``: fit a periodic design field b(t) to IGRF along the orbit (:mod:`..design.fitfield`)."""
from __future__ import annotations

import argparse
from datetime import datetime, timedelta

from ..base.atomic import output_lock
from ..base.errors import ConfigError
from ..design import fitfield
from ..design.params import check_field_epoch, check_orbit
from ..env.orbit import keplerian_period
from .common import (
    CommandError,
    add_force_argument,
    check_output,
    load_design_spacecraft,
    plain_summary,
    repo_path,
    say,
    shown_path,
)


def _parse_epoch(text: str) -> datetime:
    try:
        return datetime.fromisoformat(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an ISO date/time like 2026-03-20T00:00:00, got {text!r}") from None


def check_fit_size(harmonics: int, days: float, step: float, period: float) -> None:
    """CommandError (exit 2) unless the fit is determined and resolved: at least twice as many samples as the
    2 H + 1 unknowns per axis (``--harmonics 300 --days 0.1`` fitted 601 unknowns to 433 samples and reported a
    residual of 0.00), and the step samples the highest harmonic at least 4 times per its period T / H (also what
    bounds H: ``--harmonics 100000`` computed without end).

    Parameters
    ----------
    harmonics : int
        H.
    days : float
        Length of the fitted arc [days].
    step : float
        Sampling step [s].
    period : float
        Orbit period T [s].

    Raises
    ------
    CommandError
        Naming the option to change.
    """
    samples, unknowns = int(days * 86400.0 / step) + 1, 2 * harmonics + 1
    h_max = int(period / (4.0 * step))
    if harmonics > h_max:
        raise CommandError(f"--harmonics {harmonics}: a {step:g}-s step resolves at most {h_max} harmonics of the "
                           f"{period:.0f}-s orbit (4 samples per period of the highest); lower --harmonics or --step",
                           code=2)
    if samples < 2 * unknowns:
        raise CommandError(f"--harmonics {harmonics}: {unknowns} unknowns per axis need at least {2 * unknowns} samples, "
                           f"--days {days:g} every --step {step:g} s gives {samples}; raise --days", code=2)


def register(sub) -> None:
    p = sub.add_parser("fit-field", help="fit a periodic b(t) in orbital axes to IGRF along the orbit",
                              description=plain_summary(fitfield.__doc__))
    p.add_argument("--spacecraft", default=None,
                   help="fit along this spacecraft file's orbit (its TLE, or its circular elements, with its epoch and "
                        "RAAN) instead of --altitude/--inclination/--raan/--epoch")
    p.add_argument("--altitude", type=float, default=None, help="circular-orbit altitude [km] (default 450)")
    p.add_argument("--inclination", type=float, default=None, help="inclination [deg] (default 87)")
    p.add_argument("--harmonics", type=int, default=2, help="harmonics of the orbital rate (default 2)")
    p.add_argument("--days", type=float, default=3.0, help="days of orbit to average over (default 3)")
    p.add_argument("--step", type=float, default=20.0, help="sampling step [s] (default 20)")
    p.add_argument("--degree", type=int, default=10, help="IGRF degree/order (default 10, as in the paper)")
    p.add_argument("--raan", type=float, default=None, help="RAAN at epoch [deg] (default 0)")
    p.add_argument("--epoch", type=_parse_epoch, default=None, help="UTC epoch, ISO format (default 2026-03-20)")
    p.add_argument("--out", default=repo_path("config/field_model.yaml"),
                   help="output ROS 2 parameter file (default: config/field_model.yaml of the repository; an "
                        "existing file is kept unless --force)")
    add_force_argument(p)
    p.set_defaults(func=run)


def run(args) -> int:
    """Handler of ``magtune fit-field``: fit, print the report, write the file. Returns an exit code."""
    if args.harmonics < 1 or args.days <= 0 or args.step <= 0 or not 1 <= args.degree <= 13:
        raise CommandError("need --harmonics >= 1, --days > 0, --step > 0, 1 <= --degree <= 13", code=2)
    orbit = ("altitude", "inclination", "raan", "epoch")
    if args.spacecraft:
        given = [k for k in orbit if getattr(args, k) is not None]
        if given:
            raise ConfigError(f"--{given[0]}", None, "the orbit comes from --spacecraft: drop one of them")
        args.params = load_design_spacecraft(args, args.spacecraft)
    else:
        for k, default in zip(orbit, (450.0, 87.0, 0.0, fitfield.DEFAULT_EPOCH)):
            setattr(args, k, default if getattr(args, k) is None else getattr(args, k))
        check_orbit(args.altitude * 1e3, args.inclination, "command line")
        check_field_epoch(args.epoch, "command line", "--epoch")
        args.params = None
    period = float(args.params.orbit_period) if args.params else keplerian_period(args.altitude * 1e3)
    check_fit_size(args.harmonics, args.days, args.step, period)
    epoch = args.params.epoch if args.params else args.epoch
    check_field_epoch(epoch + timedelta(days=args.days), "command line", "--days (the fit's last sample)")
    check_output(args.out, force=args.force)
    with output_lock(args.out, "magtune fit-field", directory=False):  # one writer per output, for the whole run
        return _fit(args)


def _fit(args) -> int:
    """The fit, its report printed and the field model written to ``--out`` (locked)."""
    say("fit-field", f"sampling IGRF degree {args.degree} along {args.days:g} days of orbit every {args.step:g} s "
                     "and fitting (about a minute for the defaults)")
    p = args.params
    if p is None:
        field, report = fitfield.fit_field(args.altitude * 1e3, args.inclination, args.harmonics, args.days, args.step,
                                           args.degree, args.epoch, args.raan)
        meta = dict(altitude=args.altitude * 1e3, inclination=args.inclination, igrf_degree=args.degree,
                    days=args.days, step=args.step, raan=args.raan, epoch=args.epoch.isoformat())
    else:  # the spacecraft file's orbit: circular, or SGP4's state of its TLE at its epoch
        field, report = fitfield.fit_field_orbit(p.orbit_config(), args.harmonics, args.days, args.step, args.degree)
        meta = dict(altitude=float(p.altitude), inclination=float(p.inclination_deg), igrf_degree=args.degree,
                    days=args.days, step=args.step, raan=float(p.raan_deg), epoch=p.epoch.isoformat(),
                    spacecraft=shown_path(args.spacecraft))
        if p.tle is not None:
            meta.update(eccentricity=float(p.eccentricity), tle_line1=p.tle.line1, tle_line2=p.tle.line2)
    fitfield.write_field_model(args.out, field, report, meta)
    print(f"fit-field: {report.n_samples} IGRF-14 samples over {args.days:g} d, nodal period {field.period:.1f} s")
    print(report.markdown())
    print(f"wrote {args.out}")
    return 0
