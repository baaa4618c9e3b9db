"""``magtune export GAINS --out DIR``: the flight parameter table of a design and its equivalence vectors.

Writes into DIR: ``flight_params.yaml`` (a ROS 2 parameter file the flight nodes load),
``flight_table.json`` (every value with its unit and source, the design's provenance, the source files'
SHA-256 and the SHA-256 of its canonical content), ``flight_table.h`` (C99 ``static const`` data),
``flight_vectors.csv`` and ``flight_vectors.parquet`` (the on-board inputs and the reference outputs of a
seeded run, step by step) and ``README.md`` (columns, units, the run, how to check an implementation with
``magtune export-check``). Parameters no file gives are the flight nodes' defaults, listed as such.
Format: docs/export.md.
"""
from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

from .. import __version__
from ..base.atomic import atomic_write, output_lock
from ..base.errors import ConfigError
from ..base.paramfile import check_user_file
from ..studies import flight_table as ft
from ..studies import flight_vectors as fv
from .common import add_force_argument, add_hardware_argument, check_outputs, plain_summary, say, shown_path

PARAMS, JSON, HEADER, CSV, PARQUET, README = ("flight_params.yaml", "flight_table.json", "flight_table.h",
                                              "flight_vectors.csv", "flight_vectors.parquet", "README.md")
OUTPUTS = (PARAMS, JSON, HEADER, CSV, PARQUET, README)
#: Default length of the reference run [samples]: at 1 s, 600 s of DETUMBLE's persistence and a capture.
DEFAULT_STEPS = 800


def register(sub) -> None:
    p = sub.add_parser("export", help="flight parameter table (ROS 2 parameters, JSON, C header) and equivalence vectors",
                       description=plain_summary(__doc__))
    p.add_argument("gains", help="gains file (config/gains/sigma_*.yaml, magtune tune output)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (created; its export files are "
                                                               "kept unless --force)")
    p.add_argument("--spacecraft", "--config", dest="spacecraft", default=None, metavar="FILE",
                   help="spacecraft file (default: --config, i.e. config/spacecraft.yaml of the repository)")
    p.add_argument("--params", default=None, metavar="FILE",
                   help="ROS 2 parameter file for the flight nodes (sections /**, /**/controller, /**/mode_manager, "
                        "/**/attitude_estimator): mode thresholds, B-dot, estimator noise figures ...; without it "
                        "the nodes' defaults (listed in flight_table.json 'defaults')")
    add_hardware_argument(p)
    p.add_argument("--environment", choices=("full", "paper"), default="full",
                   help="the estimator's on-board models unless --params sets 'environment': full (default: IGRF at "
                        "the position fix, Sun of date: a flight computer's) or paper (eq. 26, no Sun)")
    p.add_argument("--steps", type=int, default=DEFAULT_STEPS,
                   help=f"samples of the reference run (default {DEFAULT_STEPS})")
    p.add_argument("--seed", type=int, default=0, help="seed of the reference run's sensor noise (default 0)")
    add_force_argument(p)
    p.set_defaults(func=run)


def _check(args) -> None:
    """Options and input files checked before any work (one line naming each, exit 2)."""
    if not 1 <= args.steps <= 1_000_000:
        raise ConfigError("--steps", None, f"expected 1 to 1000000 samples, got {args.steps}")
    if args.seed < 0:
        raise ConfigError("--seed", None, f"expected a non-negative integer, got {args.seed}")
    for path, what in ((args.gains, "expected a gains file"), (args.spacecraft, "expected a spacecraft file"),
                       (args.params, "expected a ROS 2 parameter file"), (args.hardware, "expected a hardware file")):
        if path is not None:
            check_user_file(path, what)


def run(args) -> int:
    args.spacecraft = args.spacecraft or args.config
    _check(args)
    check_outputs(args.out, OUTPUTS, force=args.force)  # before any work: nothing is replaced without --force
    with output_lock(args.out, "magtune export"):
        check_outputs(args.out, OUTPUTS, force=args.force)  # under the lock: another export may just have written
        return _export(args, Path(args.out))


def _export(args, out: Path) -> int:
    """Build the table, run the reference, write every file (the JSON last: it records the others' hashes)."""
    t0 = time.perf_counter()
    table = ft.build_table(args.gains, args.spacecraft, args.params, args.environment, args.hardware)
    defaults = sum(s == ft.DEFAULT for node in ft.FLIGHT_NODES for s in table.sources[node].values())
    say("export", f"{shown_path(args.gains)}: {defaults} flight-node parameters are the nodes' defaults"
                  + ("" if args.params else " (no --params)") + f"; on-board models: "
                  f"{table.values['attitude_estimator']['environment']}; reference run: {args.steps} samples, seed {args.seed}")
    cols = fv.simulated_inputs(table, args.steps, args.seed)
    cols.update(fv.recompute(table, cols))
    cover = fv.coverage(cols, table)
    banner = (f"magtune export {shown_path(args.gains)} (magtune {__version__}); spacecraft "
              f"{shown_path(args.spacecraft)}" + (f"; --hardware {shown_path(args.hardware)}" if args.hardware else "")
              + (f"; --params {shown_path(args.params)}" if args.params else ""))
    texts = {PARAMS: ft.parameter_file_text(table, f"Flight parameters: {banner}\nload with --ros-args --params-file "
                                                   f"{PARAMS} (docs/export.md)"),
             HEADER: ft.header_text(table, banner=f"Flight parameter table: {banner}\nData only; doubles with 17 "
                                                  "significant digits (bit-exact). docs/export.md")}
    texts[CSV] = fv.csv_text(cols)
    blobs = {**{k: v.encode() for k, v in texts.items()},
             PARQUET: fv.parquet_bytes(cols, {"magtune": f"flight vectors, schema {ft.SCHEMA_VERSION}"})}
    run_info = {"seed": args.seed, "steps": args.steps, "ts": table.gains.ts, "initial_attitude_deg": list(fv.INITIAL_ATTITUDE_DEG),
                "environment": table.values["attitude_estimator"]["environment"], "rtol": fv.RTOL,
                "tolerance": "|value - reference| <= rtol * max(|reference|, largest |value| of the column family in the run); "
                             "integer columns exact; NaN only against NaN", "coverage": cover}
    blobs[README] = _readme(table, run_info, banner).encode()
    for name in (PARAMS, HEADER, CSV, PARQUET, README):
        atomic_write(out / name, blobs[name])
    ft.read_parameter_file(out / PARAMS)  # the nodes' own reader and schemas accept what was written
    hashes = {name: hashlib.sha256(blobs[name]).hexdigest() for name in blobs}
    doc = ft.document(table, shown_path, run_info, hashes, __version__)
    atomic_write(out / JSON, json.dumps(doc, indent=1, sort_keys=True, allow_nan=False) + "\n")
    sizes = ", ".join(f"{n} {len(blobs[n]) / 1024:.0f} kB" for n in (CSV, PARQUET))
    modes = ", ".join(f"{m} {c}" for m, c in cover["steps_per_mode"].items() if c)
    print(f"wrote {out}/: {', '.join(OUTPUTS)} ({sizes}); run: {modes}; {cover['saturated_steps']} saturated; "
          f"sha256 {doc['sha256'][:16]}... ({time.perf_counter() - t0:.1f} s)")
    return 0


def _readme(table, run: dict, banner: str) -> str:
    """README.md of the export directory: the files, the run, the columns and units, the check."""
    cov = run["coverage"]
    rows = "\n".join(f"| `{n}` | {u} | {io} | {d} |" for n, u, io, d in fv.COLUMNS)
    modes = ", ".join(f"{m}: {c} (from step {cov['first_step_of_mode'][m]})" for m, c in cov["steps_per_mode"].items() if c)
    defaults = sum(s == ft.DEFAULT for node in ft.FLIGHT_NODES for s in table.sources[node].values())
    return f"""# Flight parameter table and equivalence vectors

{banner}.

| file | what |
|---|---|
| `{PARAMS}` | ROS 2 parameter file of the flight nodes: `/**` the mission data, `/**/<node>` each node's \
(`--ros-args --params-file {PARAMS}`) |
| `{JSON}` | every value with its unit, description and source; the design's provenance; SHA-256 of the sources \
and of the files here; `sha256` of its canonical content |
| `{HEADER}` | C99 `static const` data (doubles with 17 significant digits: they parse back bit for bit) |
| `{CSV}`, `{PARQUET}` | equivalence vectors: the on-board inputs and the reference outputs of each control step |

{defaults} parameters are the flight nodes' defaults (no file sets them): `{JSON}` lists them under `defaults`.

## The reference run

{run['steps']} samples at ts = {run['ts']:g} s, seed {run['seed']}, on-board models `{run['environment']}`, initial attitude
error rotation vector {run['initial_attitude_deg']} deg. The inputs are the simulated sensors along an offline run of the
plant; the outputs are what the on-board library (the flight nodes' code, `magtune_core/onboard`, sequenced as the nodes
call it: `magtune_core/sim/flight_stack.py`) computes from those inputs alone. Per sample k: the estimator (propagation
with the gyro of k-1, magnetometer and sun updates, validity), the mode logic, then the law of the mode (the `mode`
column is the mode whose law gave the row's dipole). Modes: {modes}. Saturated samples: {cov['saturated_steps']};
valid estimates: {cov['valid_steps']}; sun samples: {cov['sun_steps']}.

## Columns (SI units; body axes unless said)

| column | unit | | description |
|---|---|---|---|
{rows}

## Checking an implementation

Feed your implementation the input columns row by row (configured with `{PARAMS}` or `{HEADER}`) and write a CSV with
the `step` column and any output columns under the same names (e.g. `step,dipole_x,dipole_y,dipole_z`), then

    magtune export-check {CSV} YOUR_OUTPUTS.csv

Exit 0: every value within tolerance; 3: the first diverging step and column are named; 2: bad input.
Tolerance (rtol = {run['rtol']:g}): {run['tolerance']}.
"""
