"""Equivalence vectors: the flight software's inputs and outputs along a seeded run, and their comparison.

The inputs come from a seeded offline run (:func:`simulated_inputs`): the nonlinear plant closed by
eq. 17 on the true attitude (:func:`magtune_core.sim.simulate.simulate`, the environment of the
estimator's on-board models) from a 37-degree attitude error, and the simulated sensors of
:mod:`magtune_core.design.sensors` on it (magnetometer, Farrenkopf gyro, sun sensor, position fix:
the draws of :func:`magtune_core.sim.estimation.run_mekf`), with the estimator's noise figures. The
outputs are what the flight nodes compute from those inputs alone (:func:`recompute`:
:class:`magtune_core.sim.flight_stack.FlightStack`, i.e. the on-board library called as the nodes call
it). The outputs are not fed back to the plant: the run exercises the implementation (coarse fix,
filter, B-dot, mode logic, eq. 17, saturation), not the closed loop, which ``magtune verify`` checks.

:func:`compare` is ``magtune export-check``: every column an implementation reports, step by step,
within :data:`RTOL` of the value or, near zero, of the column family's largest magnitude in the run.
Columns and units: :data:`COLUMNS` (docs/export.md).
"""
from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass

import numpy as np

from ..base.errors import ConfigError
from ..base.paramfile import read_regular
from ..base.rotations import quat_mul
from ..design.sensors import (
    AUX_NORMALS,
    FIX,
    GYRO_U,
    GYRO_V,
    MAG,
    SUN,
    Gyro,
    Magnetometer,
    SunSensor,
    aux_rng,
    default_suite,
    draw,
    gyro,
    magnetometer,
    position_fix,
    sun_sensor,
)
from ..onboard.mekf import rotvec_quat
from ..onboard.modes import MODES
from ..sim.estimation import truth_along
from ..sim.flight_stack import FlightStack
from ..sim.simulate import simulate

#: Relative tolerance of :func:`compare`. The reference is deterministic float64; an implementation of
#: the same equations differs by the order of its operations (a few 1e-16 per operation, the filter
#: contracting them over the run) and the node's compiled MEKF equals the Python one within 1e-10 rad:
#: 1e-9 passes those and fails a gain changed in its fourth significant digit (1e-4) by five orders.
RTOL = 1e-9
#: The columns: (name, unit, input or output, description). x/y/z are body axes unless said.
COLUMNS = (
    ("step", "-", "input", "sample index k (t = k ts)"),
    ("t", "s", "input", "sim time since the spacecraft epoch (the stamp minus time_origin_ns)"),
    *[(f"field_{a}", "T", "input", f"magnetometer sample, body {a}") for a in "xyz"],
    *[(f"gyro_{a}", "rad/s", "input", f"gyro sample, body {a} (the estimator propagates from t_k to t_k+1 "
                                      "with it at step k+1)") for a in "xyz"],
    ("sun_valid", "-", "input", "1: a sun sensor sample came at this stamp (lit and in view), 0: none"),
    *[(f"sun_{a}", "-", "input", f"unit satellite-Sun vector, body {a} (NaN without a sample)") for a in "xyz"],
    *[(f"position_{a}", "m", "input", f"position fix, ECI {a} (NaN: paper environment, not read)") for a in "xyz"],
    *[(f"velocity_{a}", "m/s", "input", f"velocity of the fix, ECI {a} (NaN: paper environment)") for a in "xyz"],
    *[(f"field_ref_{a}", "T", "output", f"on-board field model at the fix, reference axes {a} (ECI in full)")
      for a in "xyz"],
    *[(f"sun_ref_{a}", "-", "output", f"on-board Sun model, unit, reference axes {a} (NaN without a sun sample)")
      for a in "xyz"],
    ("est_valid", "-", "output", "1: the estimate is valid (published with its covariance), 0: not (or no fix yet)"),
    *[(f"est_q_{a}", "-", "output", f"estimated attitude of the body w.r.t. the orbital axes, scalar first ({a}), "
                                    "q_w >= 0; (1, 0, 0, 0) before the fix") for a in "wxyz"],
    *[(f"est_rate_{a}", "rad/s", "output", f"gyro minus the estimated bias, body {a} (the gyro before the fix)")
      for a in "xyz"],
    *[(f"est_gyro_bias_{a}", "rad/s", "output", f"estimated gyro bias, body {a} (NaN before the fix)") for a in "xyz"],
    *[(f"bdot_{a}", "T/s", "output", f"filtered field derivative db/dt, body {a}") for a in "xyz"],
    ("mode", "-", "output", "flight mode whose law gave the dipole: " + ", ".join(f"{i} {m}" for i, m in enumerate(MODES))),
    *[(f"dipole_{a}", "A m^2", "output", f"commanded magnetic dipole, body {a}") for a in "xyz"],
)
NAMES = tuple(c[0] for c in COLUMNS)
INPUTS = tuple(c[0] for c in COLUMNS if c[2] == "input")
OUTPUTS = tuple(c[0] for c in COLUMNS if c[2] == "output")
#: Integer columns (compared exactly, written without a decimal point).
INTEGER = ("step", "sun_valid", "est_valid", "mode")
#: The initial attitude error of the reference run: a rotation vector [deg] (37.4 deg about an oblique axis).
INITIAL_ATTITUDE_DEG = (20.0, -30.0, 10.0)


def family(name: str) -> str:
    """A column's family: its name without the axis suffix (``dipole_x`` -> ``dipole``); the scale of its floor.

    Parameters
    ----------
    name : str
        Column name.

    Returns
    -------
    str
        The family.
    """
    head, _, tail = name.rpartition("_")
    return head if head and tail in ("x", "y", "z", "w") else name


def simulated_inputs(table, steps: int, seed: int) -> dict:
    """The inputs of the reference run (module docstring): ``steps`` samples at the gains' ts.

    Parameters
    ----------
    table : FlightTable
        The flight table (gain, limits, estimator figures, spacecraft).
    steps : int
        Samples.
    seed : int
        Seed of the sensor noise.

    Returns
    -------
    dict
        Input column name -> ndarray (``steps``,).
    """
    ctrl, est, p = table.values["controller"], table.values["attitude_estimator"], table.spacecraft
    ts, env = float(ctrl["ts"]), est["environment"]
    q0 = quat_mul(np.array([1.0, 0.0, 0.0, 0.0]), rotvec_quat(np.radians(INITIAL_ATTITUDE_DEG)))
    run = simulate(np.asarray(ctrl["gain"]).reshape(3, 6), p, ts=ts, steps=steps, q0=q0, environment=env,
                   dipole_limit=ctrl["dipole_limit"], min_field=ctrl["min_field"], residual_dipole=table.residual_dipole)
    truth = truth_along(run.t, run.q, p, env)
    base = default_suite(ts)
    suite = base.__class__(ts, Magnetometer(float(est["mag_noise_std"])),
                           Gyro(float(est["gyro_arw"]), float(est["gyro_rrw"]), base.gyro.bias), 0.0,
                           SunSensor(float(est["sun_noise_std"])), base.position)
    n1 = steps + 1
    nrm, aux = draw(np.random.default_rng(seed), n1), draw(aux_rng(seed), n1, AUX_NORMALS)
    cols = {"step": np.arange(steps), "t": run.t[:steps]}
    mag = magnetometer(suite.magnetometer, truth.b_body, nrm[:, MAG])[:steps]
    w_m, _ = gyro(suite.gyro, truth.w, ts, suite.gyro.bias, nrm[:-1, GYRO_V], nrm[:-1, GYRO_U])
    nan3 = np.full((steps, 3), np.nan)
    s_m, s_ok, r_m, v_m = nan3, np.zeros(steps, dtype=bool), nan3, nan3
    if env == "full":
        s_m, s_ok, _ = sun_sensor(suite.sun, truth.sun_body, truth.lit, aux[:, SUN])
        s_m, s_ok = np.where(s_ok[:steps, None], s_m[:steps], np.nan), s_ok[:steps]
        r_m, v_m = (a[:steps] for a in position_fix(suite.position, truth.r, truth.v, aux[:, FIX]))
    for i, a in enumerate("xyz"):
        cols[f"field_{a}"], cols[f"gyro_{a}"] = mag[:, i], w_m[:steps, i]
    cols["sun_valid"] = s_ok.astype(np.int64)
    for i, a in enumerate("xyz"):
        cols[f"sun_{a}"], cols[f"position_{a}"], cols[f"velocity_{a}"] = s_m[:, i], r_m[:, i], v_m[:, i]
    return cols


def recompute(table, inputs: dict, gain=None) -> dict:
    """The flight nodes' outputs from the input columns alone (:class:`~magtune_core.sim.flight_stack.FlightStack`).

    Parameters
    ----------
    table : FlightTable
        The flight table (its parsed node values and spacecraft configure the stack).
    inputs : dict
        Input column name -> array (``field_*``, ``gyro_*``, ``sun_valid``, ``sun_*``, ``position_*``, ``velocity_*``, ``t``).
    gain : array_like (18,), optional
        A gain replacing the table's (a perturbed implementation).

    Returns
    -------
    dict
        Output column name -> ndarray.
    """
    ctrl = dict(table.values["controller"])
    if gain is not None:
        ctrl["gain"] = np.asarray(gain, dtype=float).ravel()
    stack = FlightStack(ctrl, table.values["mode_manager"], table.values["attitude_estimator"], table.spacecraft)
    col = lambda name: np.asarray(inputs[name], dtype=float)  # noqa: E731
    b, w = np.stack([col(f"field_{a}") for a in "xyz"], 1), np.stack([col(f"gyro_{a}") for a in "xyz"], 1)
    s, r, v = (np.stack([col(f"{k}_{a}") for a in "xyz"], 1) for k in ("sun", "position", "velocity"))
    ok, t = np.asarray(inputs["sun_valid"]) != 0, col("t")
    n = len(t)
    out = {name: np.empty(n, dtype=np.int64 if name in INTEGER else float) for name in OUTPUTS}
    for k in range(n):
        st = stack.step(float(t[k]), b[k], w[k], s[k] if ok[k] else None, r[k], v[k])
        for i, a in enumerate("xyz"):
            out[f"field_ref_{a}"][k], out[f"sun_ref_{a}"][k] = st.field_ref[i], st.sun_ref[i]
            out[f"est_rate_{a}"][k], out[f"est_gyro_bias_{a}"][k] = st.rate[i], st.gyro_bias[i]
            out[f"bdot_{a}"][k], out[f"dipole_{a}"][k] = st.bdot[i], st.dipole[i]
        for i, a in enumerate("wxyz"):
            out[f"est_q_{a}"][k] = st.q[i]
        out["est_valid"][k], out["mode"][k] = int(st.valid), st.mode
    return out


def coverage(cols: dict, table) -> dict:
    """What the run exercised: samples per mode, first sample of each mode, saturated and valid samples.

    Parameters
    ----------
    cols : dict
        The vectors' columns.
    table : FlightTable
        The table (the dipole limit).

    Returns
    -------
    dict
        Plain values for the JSON document and the README.
    """
    mode = np.asarray(cols["mode"])
    m = np.stack([cols[f"dipole_{a}"] for a in "xyz"], 1)
    lim = np.asarray(table.values["controller"]["dipole_limit"], dtype=float)
    return {"steps": int(len(mode)),
            "steps_per_mode": {name: int(np.sum(mode == i)) for i, name in enumerate(MODES)},
            "first_step_of_mode": {name: int(np.argmax(mode == i)) for i, name in enumerate(MODES) if np.any(mode == i)},
            "saturated_steps": int(np.sum(np.any(np.abs(m) >= lim * (1 - 1e-12), axis=1))),
            "valid_steps": int(np.sum(np.asarray(cols["est_valid"]))),
            "sun_steps": int(np.sum(np.asarray(cols["sun_valid"])))}


# ---------------------------------------------------------------- files
def _cell(name: str, x) -> str:
    """One CSV cell: integers as integers, floats with 17 significant digits (bit-exact), NaN as ``nan``."""
    if name in INTEGER:
        return str(int(x))
    x = float(x)
    return "nan" if math.isnan(x) else f"{x:.17g}"


def csv_text(cols: dict) -> str:
    """The columns as CSV text (header row, then one row per step; floats ``%.17g``: they parse back bit for bit).

    Parameters
    ----------
    cols : dict
        Column name -> array, all of one length.

    Returns
    -------
    str
        The CSV text.
    """
    names = [n for n in NAMES if n in cols]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(names)
    for k in range(len(cols[names[0]])):
        w.writerow([_cell(n, cols[n][k]) for n in names])
    return buf.getvalue()


def parquet_bytes(cols: dict, metadata: dict | None = None) -> bytes:
    """The columns as a Parquet file (int64 and float64 columns; ``metadata`` in the schema's key-value metadata).

    Parameters
    ----------
    cols : dict
        Column name -> array.
    metadata : dict, optional
        str -> str entries.

    Returns
    -------
    bytes
        The file.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    names = [n for n in NAMES if n in cols]
    tbl = pa.table({n: np.asarray(cols[n], dtype=np.int64 if n in INTEGER else np.float64) for n in names})
    if metadata:
        tbl = tbl.replace_schema_metadata({k.encode(): v.encode() for k, v in metadata.items()})
    sink = io.BytesIO()
    pq.write_table(tbl, sink)
    return sink.getvalue()


#: Largest table read [bytes] (a 100 000-step vectors file is about 100 MB).
TABLE_LIMIT = 1 << 30


def read_columns(path, what: str = "VECTORS") -> dict:
    """A CSV (or ``.parquet``) table as column name -> float64 array; one line naming the file and the problem otherwise.

    Parameters
    ----------
    path : str or Path
        The file.
    what : str
        The argument named in errors.

    Returns
    -------
    dict
        Column -> ndarray (float64; ``nan`` cells are NaN).

    Raises
    ------
    ConfigError
        Not a table: unreadable, empty, a repeated or empty header, a ragged row or a cell that is not a number.
    """
    data = read_regular(path, limit=TABLE_LIMIT)
    if str(path).endswith(".parquet"):
        import pyarrow as pa
        import pyarrow.parquet as pq

        try:
            tbl = pq.read_table(io.BytesIO(data))
            return {n: np.asarray(tbl.column(n).to_numpy(zero_copy_only=False), dtype=float) for n in tbl.column_names}
        except (pa.ArrowException, ValueError, TypeError) as exc:
            raise ConfigError(path, None, f"{what}: not a readable Parquet table of numbers ({exc})") from None
    try:
        rows = list(csv.reader(io.StringIO(data.decode("utf-8-sig"))))
    except (UnicodeDecodeError, csv.Error) as exc:
        raise ConfigError(path, None, f"{what}: not a CSV text file ({exc})") from None
    rows = [r for r in rows if r]
    if not rows:
        raise ConfigError(path, None, f"{what}: empty; expected a header row of column names")
    head = [h.strip() for h in rows[0]]
    if len(set(head)) != len(head) or "" in head:
        raise ConfigError(path, None, f"{what}: the header names a column twice or has an empty name")
    out = np.empty((len(rows) - 1, len(head)))
    for i, r in enumerate(rows[1:]):
        if len(r) != len(head):
            raise ConfigError(path, None, f"{what}: row {i + 2} has {len(r)} cells, the header {len(head)}")
        try:
            out[i] = [float(c) for c in r]
        except ValueError:
            raise ConfigError(path, None, f"{what}: row {i + 2} has a cell that is not a number") from None
    return {h: out[:, j] for j, h in enumerate(head)}


# ---------------------------------------------------------------- the comparison
@dataclass(frozen=True)
class Comparison:
    """The result of :func:`compare`: steps and columns compared; the first divergence (None: all within tolerance)."""

    steps: int
    columns: tuple
    step: int | None = None
    column: str | None = None
    reference: float = math.nan
    value: float = math.nan
    tolerance: float = math.nan

    @property
    def passed(self) -> bool:
        """Whether every compared value is within tolerance.

        Returns
        -------
        bool
            True when there is no divergence.
        """
        return self.step is None


def scales(ref: dict) -> dict:
    """Each column family's largest finite magnitude in the reference (the near-zero floor's scale).

    Parameters
    ----------
    ref : dict
        The vectors' columns.

    Returns
    -------
    dict
        Family -> scale (0 for an all-zero or all-NaN family).
    """
    out: dict = {}
    for name, v in ref.items():
        v = np.asarray(v, dtype=float)
        m = float(np.max(np.abs(v[np.isfinite(v)]))) if np.any(np.isfinite(v)) else 0.0
        out[family(name)] = max(out.get(family(name), 0.0), m)
    return out


def compare(ref: dict, out: dict, where="OUTPUTS", rtol: float = RTOL) -> Comparison:
    """Compare an implementation's ``out`` columns with the reference ``ref`` on their common steps.

    A value passes when |value - reference| <= rtol * max(|reference|, scale of its family) (:func:`scales`);
    integer columns (:data:`INTEGER`) must be equal; NaN passes only against NaN.

    Parameters
    ----------
    ref : dict
        The vectors' columns (``step`` among them).
    out : dict
        The implementation's columns: ``step`` and any reference columns.
    where : str or Path
        The outputs' name in errors.
    rtol : float
        Relative tolerance.

    Returns
    -------
    Comparison
        Steps and columns compared, and the first divergence in step order (then column order).

    Raises
    ------
    ConfigError
        No ``step`` column, a file without rows, a column the reference does not have, a repeated step, or no
        common step.
    """
    for name, cols in (("VECTORS", ref), (where, out)):
        if "step" not in cols:
            raise ConfigError(name, "step", "no 'step' column: expected the step index of each row (the vectors' first column)")
    unknown = [c for c in out if c not in ref]
    if unknown:
        raise ConfigError(where, unknown[0], f"not a column of the vectors (expected some of: {', '.join(OUTPUTS)})")
    rs, os_ = np.asarray(ref["step"]), np.asarray(out["step"])
    for name, steps in (("VECTORS", rs), (where, os_)):
        if not len(steps):  # a header and no row: nothing was compared, which is not a pass
            raise ConfigError(name, "step", "no rows: the file has its columns but no value")
    if len(np.unique(os_)) != len(os_):
        raise ConfigError(where, "step", "a step is given twice")
    common, ri, oi = np.intersect1d(rs, os_, assume_unique=True, return_indices=True)
    if not len(common):
        raise ConfigError(where, "step", f"no step in common with the vectors (steps {int(rs.min())}..{int(rs.max())})")
    names = tuple(n for n in ref if n in out and n != "step")
    sc = scales(ref)
    bad = {}
    for n in names:
        r, o = np.asarray(ref[n], dtype=float)[ri], np.asarray(out[n], dtype=float)[oi]
        tol = np.zeros_like(r) if n in INTEGER else rtol * np.maximum(np.abs(r), sc[family(n)])
        both_nan = np.isnan(r) & np.isnan(o)
        off = ~both_nan & ~(np.abs(o - r) <= tol)
        if np.any(off):
            j = int(np.argmax(off))
            bad[n] = (j, float(r[j]), float(o[j]), float(tol[j]))
    if not bad:
        return Comparison(len(common), names)
    first = min(bad, key=lambda n: (bad[n][0], names.index(n)))
    j, r, o, tol = bad[first]
    return Comparison(len(common), names, int(common[j]), first, r, o, tol)
