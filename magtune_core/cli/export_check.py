"""``magtune export-check VECTORS OUTPUTS``: a flight implementation's outputs against the reference vectors.

VECTORS is the ``flight_vectors.csv`` (or ``.parquet``) of ``magtune export``; OUTPUTS a CSV with the
``step`` column and any of the vectors' columns under the same names (the vectors file itself passes).
Each value must lie within 1e-9 of the reference value or, near zero, of the largest magnitude of its
column family in the run (integer columns exactly; NaN only against NaN): docs/export.md. Exit 0: pass;
3: a value diverges (the first step and column are named); 2: bad input.
"""
from __future__ import annotations

from ..base.paramfile import check_user_file
from ..studies import flight_vectors as fv
from .common import plain_summary

PASSED, DIVERGED = 0, 3


def register(sub) -> None:
    p = sub.add_parser("export-check", help="compare a flight implementation's outputs with export's vectors "
                                            "(exit 0 pass, 3 diverged)", description=plain_summary(__doc__))
    p.add_argument("vectors", metavar="VECTORS", help="flight_vectors.csv (or .parquet) of magtune export")
    p.add_argument("outputs", metavar="OUTPUTS", help="CSV (or .parquet): the step column and any vectors columns")
    p.set_defaults(func=run)


def run(args) -> int:
    for path, what in ((args.vectors, "VECTORS"), (args.outputs, "OUTPUTS")):
        check_user_file(path, f"expected {what}, a CSV file", limit=fv.TABLE_LIMIT)
    ref = fv.read_columns(args.vectors, "VECTORS")
    out = fv.read_columns(args.outputs, "OUTPUTS")
    res = fv.compare(ref, out, args.outputs)
    what = f"{res.steps} steps x {len(res.columns)} columns ({', '.join(res.columns)})"
    if res.passed:
        print(f"PASS: {what} within rtol {fv.RTOL:g} (floor: rtol x the column family's largest magnitude)")
        return PASSED
    print(f"FAIL at step {res.step}, column {res.column}: {res.value!r}, reference {res.reference!r} "
          f"(difference {abs(res.value - res.reference):.3g}, tolerance {res.tolerance:.3g}); compared {what}")
    return DIVERGED
