"""What several commands share: the error-to-exit-code mapping, default paths, argument types
and the full-environment switches."""
from __future__ import annotations

import argparse
import sys

import numpy as np

from ..base.ament import AmentNotFound
from ..base.errors import ConfigError
from ..design.field import FIELD_MODELS
from ..ros.sil import SilError
from ..sim.fullenv import ENVIRONMENTS, FullEnvironmentOptions

DEFAULT_CONFIG = "config/spacecraft.yaml"
#: Magnus intervals per period for reported figures (~1e-5 relative, see bench/).
ANALYSIS_STEPS = 128


class CommandError(RuntimeError):
    """A command failed for a reason the user can act on: one line, exit status ``code``."""

    def __init__(self, message: str, code: int = 1):
        super().__init__(message)
        self.code = code


#: The one mapping from exceptions a user can cause to (exit status, message prefix).
EXIT_CODES: tuple[tuple[type[BaseException], int], ...] = (
    (ConfigError, 2),        # bad file or value: nothing was started
    (SilError, 1),           # a node failed or could not be started
    (AmentNotFound, 1),      # the ROS 2 workspace is not built
)


def run_command(args) -> int:
    """Run ``args.func(args)``, turning user-caused errors into one line on stderr + exit code."""
    name = f"magtune {args.command}" + (f" {args.bag_cmd}" if getattr(args, "bag_cmd", None) else "")
    try:
        return int(args.func(args) or 0)
    except CommandError as exc:
        print(f"{name}: {exc}", file=sys.stderr)
        return exc.code
    except KeyboardInterrupt:
        print(f"{name}: interrupted" + ("; all nodes stopped" if args.command == "sil" else ""), file=sys.stderr)
        return 130
    except tuple(cls for cls, _ in EXIT_CODES) as exc:
        code = next(c for cls, c in EXIT_CODES if isinstance(exc, cls))
        print(f"{name}: error: {exc}" if code == 2 else f"{name}: {exc}", file=sys.stderr)
        return code


def field_model_argument(p: argparse.ArgumentParser) -> None:
    """--field-model NAME | --field FILE (the design field) and --config (the spacecraft file)."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--field-model", choices=tuple(FIELD_MODELS),
                   help="design field model (default: field_model of the spacecraft file)")
    g.add_argument("--field", metavar="FILE", default=None,
                   help="design field: a periodic fit of IGRF along the orbit (magtune fit-field output, "
                        "any number of harmonics); must be fit for the spacecraft file's orbit")
    config_argument(p)


def config_argument(p: argparse.ArgumentParser) -> None:
    """--config after the subcommand too (same destination as the global option, which it overrides)."""
    p.add_argument("--config", default=argparse.SUPPRESS, help=f"spacecraft/orbit parameter file (default {DEFAULT_CONFIG})")


def positive_floats(text: str) -> list[float]:
    """argparse type: comma-separated positive numbers."""
    try:
        vals = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None
    if not vals or any(not np.isfinite(v) or v <= 0 for v in vals):
        raise argparse.ArgumentTypeError(f"expected positive numbers, got {text!r}")
    return vals


def add_environment_arguments(p: argparse.ArgumentParser, default: str = "paper") -> None:
    """--environment and the switches of the full environment (``sil`` and ``sampling``)."""
    p.add_argument("--environment", choices=ENVIRONMENTS, default=default,
                   help=f"paper: eq. 26 field, circular orbit, GG + residual dipole; full: J2 orbit, "
                        f"IGRF degree 10, GG with actual r, residual dipole, drag, SRP (docs/environment.md); "
                        f"default {default}")
    p.add_argument("--no-drag", action="store_true", help="full environment: switch drag off")
    p.add_argument("--no-srp", action="store_true", help="full environment: switch SRP off")
    p.add_argument("--no-gravity-gradient", action="store_true", help="full environment: switch gravity gradient off")
    p.add_argument("--env-field", default="igrf", choices=("igrf",) + tuple(FIELD_MODELS),
                   help="full environment field: igrf (default) or a periodic model of field.py")
    p.add_argument("--igrf-degree", type=int, default=10, help="full environment: IGRF degree (default 10)")


def environment_options(args) -> FullEnvironmentOptions:
    """FullEnvironmentOptions from the parsed --environment switches."""
    return FullEnvironmentOptions(gravity_gradient=not args.no_gravity_gradient, drag=not args.no_drag,
                                  srp=not args.no_srp, field=args.env_field, igrf_degree=args.igrf_degree)


def load_model(args):
    """The LTP design model of ``--config`` and ``--field FILE`` or ``--field-model`` (if given)."""
    from ..design.fitfield import field_for_spacecraft
    from ..design.model import AttitudeLTP
    from ..design.params import load_spacecraft

    p = load_spacecraft(args.config)
    if getattr(args, "field", None):
        return AttitudeLTP(p, field_for_spacecraft(args.field, p))
    return AttitudeLTP.from_params(p, getattr(args, "field_model", None))
