"""What several commands share: the error-to-exit-code mapping, default paths, argument types
and the full-environment switches."""
from __future__ import annotations

import argparse
import os
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
        code = int(args.func(args) or 0)
        sys.stdout.flush()  # a closed pipe (``magtune bag info | head``) shows up here, not at exit
        return code
    except BrokenPipeError:
        # the reader went away: no traceback, no second error at interpreter exit
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141  # 128 + SIGPIPE, what a shell reports for a command killed by a closed pipe
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
    p.add_argument("--field-model", choices=tuple(FIELD_MODELS),
                   help="design field model (default: field_model of the spacecraft file)")


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
    """The LTP design model of ``--config`` (and ``--field-model`` if given)."""
    from ..design.model import AttitudeLTP
    from ..design.params import load_spacecraft

    return AttitudeLTP.from_params(load_spacecraft(args.config), getattr(args, "field_model", None))
