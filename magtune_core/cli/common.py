"""What several commands share: the error-to-exit-code mapping, default paths, argument types
and the full-environment switches."""
from __future__ import annotations

import argparse
import os
import re
import sys
import tempfile
from contextlib import ExitStack, contextmanager
from pathlib import Path

import numpy as np

from ..base.ament import ROOT, AmentNotFound
from ..base.errors import ConfigError, SilError
from ..base.paramfile import check_path, check_user_file
from ..design.field import FIELD_MODELS
from ..onboard.params import TS_DEFAULT
from ..sim.fullenv import ENVIRONMENTS, FullEnvironmentOptions
from ..studies.cluster import TlsFiles


def repo_path(relative: str) -> str:
    """A default input/output path of the project, resolved against the repository (not the
    working directory), so every command finds ``config/`` and ``docs/`` from any directory.
    Paths the user types stay relative to the working directory, as usual for a command line."""
    return str(ROOT / relative)


def shown_path(path) -> str:
    """``path`` as written into generated files and messages: relative to the repository when it
    lies inside it (so regenerated docs do not depend on where the checkout is), else as given."""
    try:
        return str(Path(path).resolve().relative_to(ROOT))
    except ValueError:
        return str(path)


#: The spacecraft/orbit parameter file every command reads by default.
DEFAULT_CONFIG = repo_path("config/spacecraft.yaml")


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


def plain_summary(doc: str | None) -> str:
    """The first paragraph of a module docstring as plain text for ``--help``: reST roles
    (``:mod:`x```) and inline literals (double backticks) become their bare text."""
    text = (doc or "").strip().split("\n\n")[0]
    text = re.sub(r":[a-z]+:`~?([^`]+)`", r"\1", text)
    return " ".join(text.replace("``", "").replace("`", "").split())


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
    p.add_argument("--config", default=argparse.SUPPRESS,
                   help="spacecraft/orbit parameter file (default: config/spacecraft.yaml of the repository)")


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
                   help=f"default {default}. paper: eq. 26 field, circular orbit, GG + residual dipole; full: J2 orbit, "
                        f"IGRF degree 10, GG with actual r, residual dipole, drag, SRP (docs/environment.md)")
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


#: Choices of ``--start-scale`` (CmaSettings.start_scale) and their help.
START_SCALES = ("feasible", "gain")
START_SCALE_HELP = ("coordinates of the first CMA-ES run under the hold constraint: 'feasible' = each entry's "
                    "feasible range (default; 5-10x closer to the optimum in 90 s on the paper's periodic field), "
                    "'gain' = the start gain's own entries (faster on a constant field; docs/tuning.md)")
GAIN_MARGIN_HELP = ("feasible gains keep the sample-and-hold loop at --ts stable with K times this factor "
                    "(2 = 6 dB; 0 = no constraint, the paper's unconstrained problem; design/sampled.py); given "
                    "with or without --ts, a single-period constraint replaces the design spec")


def hold_constraint(args):
    """The digital-implementation constraint of ``--ts`` / ``--gain-margin`` (None for margin 0),
    checked: one line naming the option, exit 2, before any work."""
    from ..design.sampled import HoldConstraint

    ts = TS_DEFAULT if args.ts is None else args.ts
    gm = 2.0 if args.gain_margin is None else args.gain_margin
    if not (np.isfinite(ts) and ts > 0):
        raise ConfigError("--ts", None, f"must be a positive sample period in seconds, got {ts:g}")
    if not (np.isfinite(gm) and (gm == 0 or gm >= 1)):
        raise ConfigError("--gain-margin", None, f"must be 0 (no constraint) or a factor >= 1, got {gm:g}")
    return HoldConstraint(ts, gm) if gm else None


SPEC_HELP = ("design spec: the hard requirements (sample-period range, hold gain margin, dipole budget) and the "
             "pointing requirements of verify (default config/design.yaml; docs/requirements.md)")


def add_spec_argument(p: argparse.ArgumentParser) -> None:
    """``--spec DESIGN_SPEC``: the one option every command reading the requirements takes (and ``--hardware``:
    the torquers' limit the spec's dipole budget resolves against)."""
    p.add_argument("--spec", metavar="DESIGN_SPEC", default=None, help=SPEC_HELP)
    add_hardware_argument(p)


HARDWARE_HELP = ("hardware file: the torquers' and sensors' datasheet figures (config/hardware.yaml; docs/hardware.md); "
                 "default: none, the spacecraft file's node sections and the nodes' defaults")


def add_hardware_argument(p: argparse.ArgumentParser) -> None:
    """``--hardware FILE``: optional; without it every value is what it was before hardware files."""
    p.add_argument("--hardware", metavar="FILE", default=None, help=HARDWARE_HELP)


def load_hardware_file(args):
    """The hardware file of ``--hardware`` (None without one), read once per command and kept on ``args``:
    one line and exit 2 if bad, before any work."""
    from ..design.hardware import load_hardware

    path = getattr(args, "hardware", None)
    if path is None:
        return None
    loaded = vars(args).setdefault("_hardware", {})
    if str(path) not in loaded:
        loaded[str(path)] = load_hardware(path)
    return loaded[str(path)]


def load_design_spec(args, model=None):
    """The requirements of ``--spec`` (default ``config/design.yaml``; the built-in defaults when that
    file is absent), the dipole limit resolved against ``--hardware``'s torquers (the weakest rod), else
    ``--config``'s: one line and exit 2 if bad."""
    from dataclasses import replace

    from ..design.requirements import Requirements, load_requirements, spacecraft_dipole_limit

    hw = load_hardware_file(args)
    if hw is not None:
        from ..base.paramfile import load_ros_params
        from ..design.hardware import check_spacecraft_agrees

        check_spacecraft_agrees(hw, load_ros_params(args.config), args.config)
    limit = hw.dipole_limit if hw is not None and hw.dipole_limit is not None else spacecraft_dipole_limit(args.config)
    path = args.spec or repo_path("config/design.yaml")
    if args.spec is None and not Path(path).is_file():
        return replace(Requirements.from_mapping({}, limit), hardware=hw)
    check_user_file(path, "expected a design spec")  # a regular file within the size limit, before it is parsed
    return replace(load_requirements(path, limit), source=shown_path(path), hardware=hw)  # recorded: no checkout path


def load_design_spacecraft(args, path=None):
    """The spacecraft of ``--config`` (or ``path``) for a design command, loaded once per command (kept on
    ``args``): an orbit the periodic circular model cannot represent (eccentricity over the bound) is one line
    and exit 2 before any work; an orbit from a TLE is reported in one line (its eccentricity, mean motion and
    period)."""
    from ..design.params import check_design_orbit, load_spacecraft, orbit_summary

    path = path or args.config
    loaded = vars(args).setdefault("_spacecraft", {})
    if str(path) not in loaded:
        p = load_spacecraft(path)
        check_design_orbit(p, path)
        if p.tle is not None:
            say(args.command, orbit_summary(p))
        loaded[str(path)] = p
    return loaded[str(path)]


def load_model(args):
    """The LTP design model of ``--config`` and ``--field FILE`` or ``--field-model`` (if given)."""
    from ..design.fitfield import field_for_spacecraft
    from ..design.model import AttitudeLTP

    p = load_design_spacecraft(args)
    if getattr(args, "field", None):
        return AttitudeLTP(p, field_for_spacecraft(args.field, p))
    return AttitudeLTP.from_params(p, getattr(args, "field_model", None))


def say(command: str, text: str) -> None:
    """One progress line on stderr (``magtune COMMAND: text``), so stdout stays the result."""
    print(f"magtune {command}: {text}", file=sys.stderr, flush=True)


def add_force_argument(p: argparse.ArgumentParser) -> None:
    """``--force``: the one switch that lets a command overwrite an existing output file."""
    p.add_argument("--force", action="store_true",
                   help="overwrite output files that already exist (without it the command refuses, "
                        "before any work, so a tracked file is never replaced by accident)")


def add_oversubscribe_argument(p: argparse.ArgumentParser) -> None:
    """``--oversubscribe``: allow more local ``--workers`` than the machine has cores (:func:`check_workers`)."""
    p.add_argument("--oversubscribe", action="store_true",
                   help="allow more local --workers than this machine's cores (without it such a request is refused: "
                        "every worker would share a core and the run would only get slower)")


def check_workers(args) -> None:
    """ConfigError (exit 2, before any work) for ``--workers`` below 1, or above this machine's cores for local
    workers unless ``--oversubscribe`` (``campaign --workers 1000`` on 2 cores started hundreds of processes, load
    57, and no run finished). Workers of an existing cluster (``--scheduler``) are that cluster's: not checked here.

    Parameters
    ----------
    args : argparse.Namespace
        With ``workers`` (int or None: the default), optionally ``oversubscribe`` and ``scheduler``.

    Raises
    ------
    ConfigError
        Naming ``--workers`` and the fix.
    """
    n = getattr(args, "workers", None)
    if n is None:
        return
    if n < 1:
        raise ConfigError("--workers", None, f"expected at least 1, got {n}")
    cores = os.cpu_count() or 1
    if n > cores and getattr(args, "scheduler", None) is None and not getattr(args, "oversubscribe", False):
        raise ConfigError("--workers", None, f"{n} local workers on {cores} cores: give at most {cores}, or "
                                             "--oversubscribe if that is what you want")


def _nearest_existing(path: Path) -> Path:
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def _check_writable_location(path: Path, option: str) -> None:
    """``path`` (absent or not) can be created: its nearest existing ancestor is a writable directory."""
    anc = _nearest_existing(path.parent)
    if not anc.is_dir():
        raise ConfigError(path, None, f"cannot create it: {anc} is not a directory (choose another {option})")
    _probe_directory(anc, path, option)


def _probe_directory(directory: Path, path: Path, option: str) -> None:
    """Create and delete a temporary file in ``directory``: the only check that also holds for
    root (``os.access`` says yes to everything) and for read-only or pseudo file systems."""
    try:
        with tempfile.TemporaryFile(dir=directory):
            pass
    except OSError as exc:
        raise ConfigError(path, None, f"cannot write in directory {directory}: {exc.strerror or exc} "
                                      f"(choose another {option})") from None


def check_output(path, *, force: bool = False, option: str = "--out", directory: bool = False) -> Path:
    """The one output-path check of every command, run before any work.

    A file output (``directory=False``) that exists is refused unless ``force`` (the message
    names ``--force`` and ``option``), a directory in its place is refused, and the place must be
    writable: an existing file must be writable, an absent one must be creatable (its nearest
    existing ancestor a writable directory). A directory output (``directory=True``, e.g. a log
    or results directory that may hold earlier files) must be an existing writable directory or
    creatable; use :func:`check_outputs` for the named files a command writes inside it.

    Returns
    -------
    Path
        ``path`` as a Path (not resolved: relative paths stay relative to the working directory).

    Raises
    ------
    ConfigError
        One line naming the path, what is wrong and the option to change (exit status 2).
    """
    path = Path(path)
    check_path(path)  # a symbolic link loop: one line, the same in every command
    if path.is_symlink() and not path.exists():  # dangling: mkdir or open would fail after the work (a traceback)
        raise ConfigError(path, None, f"is a symbolic link to {os.readlink(path)!r}, which does not exist: remove it "
                                      f"or choose another {option}")
    if directory:
        if path.exists() and not path.is_dir():
            raise ConfigError(path, None, f"exists and is not a directory (choose another {option})")
        if path.is_dir():
            _probe_directory(path, path, option)
        else:
            _check_writable_location(path, option)
        return path
    if path.is_dir():
        raise ConfigError(path, None, f"is a directory; {option} expects a file name")
    if path.exists():
        if not force:
            raise ConfigError(path, None, f"exists; pass --force to overwrite it, or {option} to write elsewhere")
        if not os.access(path, os.W_OK):
            raise ConfigError(path, None, f"exists and is not writable (choose another {option})")
        _probe_directory(path.parent, path, option)
        return path
    _check_writable_location(path, option)
    return path


def check_outputs(directory, names, *, force: bool = False, option: str = "--out") -> list[Path]:
    """:func:`check_output` for the files ``names`` a command writes into ``directory``: the
    directory must be usable and none of the files may exist unless ``force``.

    Returns
    -------
    list of Path
        ``directory / name`` for each name, in order.
    """
    d = check_output(directory, option=option, directory=True)
    existing = [n for n in names if (d / n).exists()]
    if existing and not force:
        raise ConfigError(d, None, f"already holds {', '.join(existing)}; pass --force to overwrite, "
                                   f"or {option} to write elsewhere")
    return [check_output(d / n, force=force, option=option) for n in names]


#: ``--scheduler`` of the commands that run Monte Carlo campaigns (campaign, verify).
CAMPAIGN_SCHEDULER_HELP = ("tls://HOST:PORT (or tcp://, unauthenticated) of an existing Dask scheduler (default: a "
                           "LocalCluster on this machine, TLS with a temporary certificate: no other client can "
                           "connect); 'synchronous' runs in this process without Dask")
#: ``--scheduler`` of the tuners (tune, front).
TUNER_SCHEDULER_HELP = ("tls://HOST:PORT (or tcp://, unauthenticated) of an existing Dask scheduler: each population's "
                        "candidates are evaluated as tasks on its workers instead of --workers local processes, "
                        "split in one part per worker thread (the same gain as a local run with --workers equal to "
                        "the cluster's threads; docs/tuning.md)")


def add_scheduler_arguments(p, scheduler_help: str) -> None:
    """``--scheduler`` and the ``--tls-*`` files of an existing (secured) Dask cluster."""
    p.add_argument("--scheduler", default=None, help=scheduler_help)
    p.add_argument("--tls-ca-file", default=None, help="tls:// scheduler: CA certificate (PEM) the cluster's "
                                                       "certificates are signed with")
    p.add_argument("--tls-cert", default=None, help="tls:// scheduler: this client's certificate (PEM)")
    p.add_argument("--tls-key", default=None, help="tls:// scheduler: this client's private key (PEM)")


def scheduler_options(args, command: str, synchronous: bool = False):
    """(scheduler, TlsFiles or None) of the command line, checked before anything starts: one line
    naming the option and the fix, exit 2; a tcp:// scheduler is accepted with a warning (anyone who
    reaches it can run code on its workers). ``synchronous``: the command also takes 'synchronous'."""
    sched = args.scheduler
    forms = "tls://HOST:PORT, tcp://HOST:PORT or synchronous" if synchronous else "tls://HOST:PORT or tcp://HOST:PORT"
    if sched is not None and not (sched.startswith(("tls://", "tcp://")) or (synchronous and sched == "synchronous")):
        raise ConfigError("--scheduler", None, f"expected {forms}, got {sched!r}")
    tls = TlsFiles(args.tls_ca_file, args.tls_cert, args.tls_key)
    if tls.given() and (sched is None or sched == "synchronous"):
        raise ConfigError("--tls-ca-file", None, "TLS files are for an existing cluster: add --scheduler tls://HOST:PORT")
    if sched and sched != "synchronous":
        from ..studies.cluster import scheduler_security

        scheduler_security(sched, tls)  # ConfigError for a missing file or an incomplete set
        if sched.startswith("tcp://"):
            print(f"{command}: warning: {sched} is unauthenticated; anyone who can reach it can run code on its "
                  "workers (use tls://, docs/campaigns.md)", file=sys.stderr)
    return sched, tls if tls.given() else None


@contextmanager
def cluster_executor(scheduler: str | None, tls=None):
    """The tuner's executor on the cluster at ``scheduler`` (:func:`magtune_core.studies.cluster.executor`),
    or None (the local pool) without one; an unreachable scheduler or unusable workers: one line, exit 1."""
    if scheduler is None:
        yield None
        return
    from ..studies import cluster

    with ExitStack() as stack:
        try:
            ex = stack.enter_context(cluster.executor(scheduler, tls))
        except OSError as exc:  # distributed raises OSError subclasses on connect timeouts
            raise CommandError(f"cannot reach the Dask scheduler {scheduler}: {exc}") from None
        except cluster.ClusterError as exc:
            raise CommandError(str(exc)) from None
        yield ex
