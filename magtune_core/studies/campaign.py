"""Monte Carlo campaigns: dispersed closed-loop runs, batched, executed as dask.distributed tasks.

``magtune campaign SPEC.yaml --runs N --out DIR`` (the command: :mod:`magtune_core.cli.campaign`)

A campaign spec (YAML, three sections and optional ones, each validated by its :class:`Field` schema below)
names the gains file(s), the spacecraft file, the environment, the run length and Ts, the
dispersions and the pass/fail criteria. Run ``i`` (0 <= i < N) draws its parameters from its own
generator ``numpy.random.default_rng([seed, i])`` in a fixed order (every draw is made even
when its spread is zero, so changing one spread never reshuffles the others) and its sensor
noise from ``default_rng([seed, i, 1])``. Runs are grouped in batches of ``batch_size``
consecutive indices, each batch one Dask task that advances all its runs together
(:func:`magtune_core.sim.batch.simulate_batch`). A run's result therefore depends on the spec,
the seed and its index only: the same on 1 worker, 2 workers or a cluster, and the same when a
worker dies during the campaign: every task carries the spec by value, the scheduler re-runs
the tasks of a dead worker elsewhere, and a task that still fails is resubmitted a bounded
number of times (:data:`TASK_RETRIES`, :data:`RESUBMITS`); runs that never completed are
``failed`` with the reason (``campaign.json`` ``failed_runs``) and the command exits 1. The
cluster is closed to other users by default (:mod:`.cluster`).

Dispersions (all optional; zero spread = nominal):

* inertia: principal moments ``I_k (1 + e_k)``, ``e_k ~ N(0, inertia_rel_std_k^2)`` clipped at 3 sigma;
* residual dipole [A m^2] per body axis: ``N(residual_dipole_mean, residual_dipole_std^2)``;
* initial attitude: a rotation about a uniformly distributed axis by an angle uniform in
  ``[0, attitude_max_deg]`` from the orbital frame; initial rate error ``dw(0) = rate_mean + U(-rate_max, rate_max)``
  per axis [rad/s] (the paper's dw(0) = [1e-3, 2e-3, 0] is the default mean);
* epoch and RAAN (full environment): uniform in ``[epoch_min, epoch_max]``, ``[raan_min_deg, raan_max_deg]``;
* sensors: magnetometer white noise std [T] and bias ``N(0, mag_bias_std^2)`` per axis, gyro
  noise [rad/s] and bias likewise, attitude-determination error std [rad] (the model of the
  ``attitude_sensors`` node, :mod:`magtune_core.sim.batch`);
* dipole limit per axis [A m^2]: uniform in ``[dipole_limit_min, dipole_limit_max]``.

Optional sections: ``modes`` (deployment campaigns: the mode machine and B-dot, with ``campaign.modes``),
``estimator`` (the MEKF in the loop, with ``campaign.attitude: estimator``) and ``torquers`` (the torquers'
field at the magnetometer and their duty cycle, every run: the simulator/sensors/controller nodes' schema
TORQUER_FIELDS, docs/torquers.md). ``faults``: a list of injected faults flown by every run (the scenario
file's schema, design.faults.FAULT_FIELDS, or spec strings ``KIND@T[:DURATION][,axis=A][,value=V]``; the
kinds of sim.fault_kernels.FAULT_CODE), e.g. to measure what a detector sees across dispersed runs.
``estimator.torquer_watch: true`` replays the estimator node's torquer watch over every run
(sim/batch_torquer.py): columns :data:`TORQUER_COLUMNS`; off by default (its memory and CPU, docs/campaigns.md).

Figures of merit per run, from the true attitude at every controller instant (pointing error
= rotation angle between body and orbital axes, ``2 asin(|q_vec|)`` [deg],
:func:`magtune_core.sim.metrics.pointing_error_deg`):
settling time (first instant after which the error stays below ``settle_threshold_deg``),
RMS and max pointing error after settling (window ``t >= max_settling_orbits T``, the instant
by which the criteria require settling: the same window for every run), final error, peak and RMS of |m| (whole run),
saturation and weak-field fractions; pass/fail against the criteria. A run is ``ok``,
``diverged`` (non-finite state or |w| > 1 rad/s at some step) or ``failed`` (an exception while
setting it up or running it: the message is kept); every run has a row, none is dropped.

Outputs in DIR: ``runs.parquet`` (one row per run: index, gains, status, parameters,
figures, pass and reasons), ``histories/batch_NNNNN.npz`` (pointing error, |m| and |dw| of every
run every ``history_step`` seconds, float32), ``campaign.json`` (resolved spec, counts, timing)
and ``spec.yaml`` (the input). ``magtune campaign-report DIR`` adds ``summary.md``,
``envelopes.png`` (5/50/95 % envelopes) and ``histograms.png``.
"""
from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field, replace
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import yaml

from ..base import jsonout
from ..base.ament import ROOT
from ..base.atomic import atomic_output, atomic_write
from ..base.errors import ConfigError
from ..base.paramfile import load_user_yaml
from ..base.schema import Field, parse
from ..design import faults as fl
from ..design.gains import load_gains
from ..design.params import SpacecraftParams, load_spacecraft, parse_epoch
from ..onboard.modes import MODES, POINTING, ModeParams
from ..onboard.params import BDOT_FIELDS, ESTIMATOR_FIELDS, MODE_FIELDS, TORQUER_FIELDS, check_modes
from ..onboard.sensor_watch import GYRO_FAULT, MAG_AMBIGUOUS, MAG_FAULT
from ..onboard.torquer_watch import AXES
from ..onboard.torquers import Torquers
from ..sim.batch import BatchEstimator, BatchModes, BatchRuns, SensorNoise, simulate_batch
from ..sim.batch_torquer import replay, watch_params
from ..sim.fault_kernels import FAULT_CODE, NOT_BATCHED
from ..sim.fullenv import ENVIRONMENTS, FullEnvironmentOptions, nominal_orbit_period, substeps_for
from ..sim.metrics import settling_time
from ..sim.simulate import DW0
from ..sim.substeps import Substeps, substeps_for_rate
from . import cluster

#: Section ``campaign``: what is run.
CAMPAIGN_FIELDS = (
    Field("name", "str", "campaign name (reports)", "campaign"),
    Field("seed", "int", "master seed: run i draws from default_rng([seed, i])", nonnegative=True),
    Field("gains", "str", "gains file (config/gains/sigma_*.yaml); a list of files runs every dispersion with each"),
    Field("spacecraft", "str", "spacecraft parameter file", "config/spacecraft.yaml"),
    Field("environment", "str", "plant environment", "full", choices=ENVIRONMENTS),
    Field("orbits", "float", "run length [nominal orbits]", 5.0, positive=True),
    Field("ts", "float", "controller sample period Ts [s]", 1.0, positive=True),
    Field("substeps", "int", "RK4 steps per Ts (0: at most 0.5 s per step, fullenv.substeps_for)", 0, nonnegative=True),
    Field("batch_size", "int", "runs per Dask task (advanced together as arrays)", 250, positive=True),
    Field("history_step", "float", "time step of the stored histories [s]", 60.0, positive=True),
    Field("drag", "bool", "full environment: aerodynamic drag", True),
    Field("srp", "bool", "full environment: solar radiation pressure", True),
    Field("gravity_gradient", "bool", "full environment: gravity gradient", True),
    Field("field", "str", "full environment: igrf or a periodic model of design/field.py", "igrf"),
    Field("igrf_degree", "int", "full environment: IGRF degree", 10, positive=True),
    Field("arg_lat_deg", "float", "full environment: argument of latitude at the epoch [deg] (default: the "
          "spacecraft file's arg_latitude)", None),
    Field("min_field", "float", "weak-field guard of the controller [T]", 1e-7, positive=True),
    Field("modes", "bool", "fly the flight modes from deployment (DETUMBLE: B-dot, ACQUISITION, POINTING: eq. 17; "
          "thresholds in section modes): a deployment campaign", False),
    Field("attitude", "str", "the controller's attitude: truth (the truth plus attitude_noise_std) or estimator "
          "(the MEKF on magnetometer, gyro and sun sensor, section estimator)", "truth", choices=("truth", "estimator")),
)

#: Section ``dispersions``.
DISPERSION_FIELDS = (
    Field("inertia_rel_std", "float[]", "1-sigma relative error of Ixx, Iyy, Izz (normal, clipped at 3 sigma)",
          (0.0, 0.0, 0.0), size=3, nonnegative=True),
    Field("residual_dipole_mean", "float[]", "mean residual dipole per body axis [A m^2]", (1.0, 1.0, 1.0), size=3),
    Field("residual_dipole_std", "float[]", "1-sigma residual dipole per body axis [A m^2]", (0.0, 0.0, 0.0),
          size=3, nonnegative=True),
    Field("attitude_max_deg", "float", "initial attitude: rotation by U(0, max) about a random axis [deg]", 0.0,
          nonnegative=True),
    Field("rate_mean", "float[]", "initial rate error dw(0) mean [rad/s]", DW0, size=3),
    Field("rate_max", "float[]", "initial rate error: + U(-max, max) per axis [rad/s]", (0.0, 0.0, 0.0), size=3,
          nonnegative=True),
    Field("epoch_min", "str", "epoch range start (UTC, ISO 8601; default: the spacecraft file's epoch)", ""),
    Field("epoch_max", "str", "epoch range end (UTC, ISO 8601; default epoch_min)", ""),
    Field("raan_min_deg", "float", "RAAN range start [deg] (default: the spacecraft file's raan)", None),
    Field("raan_max_deg", "float", "RAAN range end [deg] (default raan_min_deg)", None),
    Field("mag_noise_std", "float", "magnetometer white noise std [T]", 0.0, nonnegative=True),
    Field("mag_bias_std", "float", "magnetometer bias 1-sigma per axis [T]", 0.0, nonnegative=True),
    Field("gyro_noise_std", "float", "gyro white noise std [rad/s]", 0.0, nonnegative=True),
    Field("gyro_bias_std", "float", "gyro bias 1-sigma per axis [rad/s]", 0.0, nonnegative=True),
    Field("attitude_noise_std", "float", "attitude-determination error std per axis [rad]", 0.0, nonnegative=True),
    Field("dipole_limit_min", "float", "per-axis dipole limit range start [A m^2]", 50.0, positive=True),
    Field("dipole_limit_max", "float", "per-axis dipole limit range end [A m^2] (default dipole_limit_min)", None,
          positive=True),
    Field("attitude_uniform", "bool", "initial attitude uniformly distributed over all rotations (a normalized "
          "4-D normal quaternion; replaces attitude_max_deg)", False),
    Field("gyro_arw", "float", "gyro angle random walk sigma_v [rad/s^0.5] (adds to gyro_noise_std^2 ts)", 0.0,
          nonnegative=True),
    Field("gyro_rrw", "float", "gyro rate random walk sigma_u [rad/s^1.5]", 0.0, nonnegative=True),
    Field("sun_noise_std", "float", "sun sensor angle error std per axis [rad] (campaign.attitude: estimator)", 0.0,
          nonnegative=True),
)

#: Section ``criteria`` (a run passes when it is ok and meets every criterion given).
CRITERIA_FIELDS = (
    Field("settle_threshold_deg", "float", "pointing error below which the run counts as settled [deg]", 2.0,
          positive=True),
    Field("max_settling_orbits", "float", "settling time limit [nominal orbits]", 2.0, positive=True),
    Field("max_pointing_deg", "float", "limit of the max pointing error in steady state (t >= max_settling_orbits T) [deg]",
          None, positive=True),
    Field("max_rms_pointing_deg", "float", "limit of the RMS pointing error in steady state [deg]", None, positive=True),
    Field("max_peak_dipole", "float", "limit of the peak |m| [A m^2]", None, positive=True),
    Field("max_saturation_fraction", "float", "limit of the fraction of saturated controller steps (whole run)",
          None, nonnegative=True),
    Field("max_steady_saturation_fraction", "float", "limit of the fraction of saturated controller steps in "
          "steady state (t >= max_settling_orbits T)", None, nonnegative=True),
    Field("max_deployment_orbits", "float", "deployment campaigns: limit of the time to settled pointing "
          "[nominal orbits]", None, positive=True),
)

#: Section ``modes`` (with ``campaign.modes``): the mode machine's and the B-dot law's schema, the one the
#: mode manager node, the controller and the offline mode loop read (onboard/params.py).
MODES_SECTION_FIELDS = MODE_FIELDS + BDOT_FIELDS
#: ``estimator.torquer_watch``: the node's field (onboard/params.py, on in flight) with the campaign's default, off: the
#: replay costs CPU and the recording ~105 B per run-step of memory (sim/batch_torquer.py, docs/campaigns.md).
TORQUER_WATCH_FIELD = Field("torquer_watch", "bool", "replay the attitude_estimator's torquer watch over every run "
                            "(sim/batch_torquer.py; rows torquer_unit, torquer_time, torquer_kind, torquer_verdicts)", False)
#: Section ``estimator`` (with ``campaign.attitude: estimator``): the filter's fields of the attitude_estimator
#: node's schema (onboard/params.py ESTIMATOR_FIELDS, the same Field objects: names, defaults, bounds), but
#: :data:`TORQUER_WATCH_FIELD`.
ESTIMATOR_SECTION_FIELDS = tuple(f for f in ESTIMATOR_FIELDS if f.name in BatchEstimator.__dataclass_fields__
                                 and f.name != TORQUER_WATCH_FIELD.name) + (TORQUER_WATCH_FIELD,)

SECTIONS = {"campaign": CAMPAIGN_FIELDS, "dispersions": DISPERSION_FIELDS, "criteria": CRITERIA_FIELDS,
            "modes": MODES_SECTION_FIELDS, "estimator": ESTIMATOR_SECTION_FIELDS, "torquers": TORQUER_FIELDS}
STATUSES = ("ok", "diverged", "failed")
#: Figures of merit (columns of runs.parquet) and their units, in report order.
FIGURES = (("settling_time", "s"), ("max_pointing_deg", "deg"), ("rms_pointing_deg", "deg"),
           ("final_pointing_deg", "deg"), ("peak_dipole", "A m^2"), ("rms_dipole", "A m^2"),
           ("saturation_fraction", "-"), ("steady_saturation_fraction", "-"), ("weak_field_fraction", "-"))
#: Figures of a deployment campaign (``campaign.modes``): time to detumble (DETUMBLE left for the first time),
#: to POINTING (first entry), to settled pointing (from then on in POINTING with the error below
#: ``settle_threshold_deg``), the number of mode transitions.
MODE_FIGURES = (("detumble_time", "s"), ("pointing_time", "s"), ("settled_time", "s"), ("transitions", "-"))
#: Figures of a campaign with the estimator in the loop (``campaign.attitude: estimator``), over the steady-state
#: window: RMS estimation error per body axis, the fraction of samples inside 3 sigma per axis, mean NEES (3 for
#: a consistent filter), the coarse fix's time.
#: The sensor watch's verdicts (onboard.sensor_watch codes) as the unit a campaign row names (``fdir_unit``; with
#: ``fdir_time`` [s] of the first verdict and ``fdir_verdicts``, the run's count).
FDIR_UNITS = {MAG_FAULT: "magnetometer", MAG_AMBIGUOUS: "magnetometer (no sun)", GYRO_FAULT: "gyro"}
#: The torquer watch's columns (``estimator.torquer_watch``): the first torquer named ("torquer x|y|z", "" none), its
#: time [s] (nan: none), the kind the watch names it with at the run's end (onboard.torquer_watch.KINDS), verdicts in
#: all; per axis its first declaration [s] and its kind at the end (a wrong first axis does not hide a later right one).
TORQUER_COLUMNS = ("torquer_unit", "torquer_time", "torquer_kind", "torquer_verdicts") + tuple(
    f"torquer_{c}_{a}" for c in ("time", "kind") for a in AXES)
ESTIMATION_FIGURES = tuple((f"est_rms_{a}_deg", "deg") for a in "xyz") + tuple(
    (f"est_inside_3sigma_{a}", "-") for a in "xyz") + (("est_nees_mean", "-"), ("est_fix_time", "s"))


@dataclass
class CampaignSpec:
    """A validated campaign: the sections' values plus the loaded spacecraft and gains (so a task
    carries everything a remote worker needs; workers read no file)."""

    path: str
    campaign: dict
    dispersions: dict
    criteria: dict
    gains_files: list
    K: np.ndarray  #: (G, 3, 6) one gain per gains file
    p: SpacecraftParams
    epoch_min: datetime
    epoch_max: datetime
    raw: dict = field(default_factory=dict)
    modes: dict = field(default_factory=dict)  #: section ``modes`` (parsed; used with ``campaign.modes``)
    estimator: dict = field(default_factory=dict)  #: section ``estimator`` (parsed; with ``campaign.attitude: estimator``)
    torquers: dict = field(default_factory=dict)  #: section ``torquers`` (parsed: coupling, duty cycle; every run)
    faults: tuple = ()  #: section ``faults`` (design.faults.Fault, every run)

    @property
    def seed(self) -> int:
        return int(self.campaign["seed"])

    @property
    def substeps(self) -> Substeps:
        """RK4 sub-steps per Ts (sim.substeps.Substeps): ``campaign.substeps`` > 0 that many throughout; 0 = from
        at most 0.5 s per step (fullenv.substeps_for), re-chosen every step from each run's rate up to what the
        fastest drawable initial rate needs (the bound |rate_mean| + rate_max + W0 per axis, deployment
        campaigns); a duty cycle's switch-off on the grid (onboard.torquers.Torquers.substeps)."""
        ts, s = self.campaign["ts"], int(self.campaign["substeps"])
        need = s
        if self.campaign["modes"]:
            d = self.dispersions
            bound = np.abs(d["rate_mean"]) + d["rate_max"] + np.array([0.0, 0.0, self.p.orbit_rate])
            need = substeps_for_rate(bound, ts)
        fewest = max(s, need) if s > 0 else substeps_for(ts)
        return Substeps.ladder(ts, fewest, max(fewest, need), self.batch_torquers())

    def batch_modes(self) -> BatchModes | None:
        """The flight modes every run flies (``campaign.modes``; section ``modes``), else None."""
        if not self.campaign["modes"]:
            return None
        v = self.modes
        return BatchModes(ModeParams(**{f.name: v[f.name] for f in MODE_FIELDS}), bdot_gain=v["bdot_gain"],
                          bdot_cutoff=v["bdot_cutoff"])

    def batch_estimator(self) -> BatchEstimator | None:
        """The estimator every run flies (``campaign.attitude: estimator``; section ``estimator``; with
        ``campaign.modes`` the full stack: its validity gate on), else None."""
        if self.campaign["attitude"] != "estimator":
            return None
        v = {f.name: self.estimator[f.name] for f in ESTIMATOR_SECTION_FIELDS}
        v["validity_gate"] = v["validity_gate"] or self.campaign["modes"]  # the full stack trusts only a valid estimate
        return BatchEstimator(**v, sun_sensor_std=self.dispersions["sun_noise_std"])

    def batch_torquers(self) -> Torquers:
        """The torquers' coupling into the magnetometer and duty cycle every run flies (section ``torquers``,
        the schema of the simulator, sensors and controller nodes; docs/torquers.md)."""
        return Torquers.from_values(self.torquers)

    def env_options(self, epoch: datetime, raan_deg: float) -> FullEnvironmentOptions:
        c = self.campaign
        return FullEnvironmentOptions(gravity_gradient=c["gravity_gradient"], drag=c["drag"], srp=c["srp"],
                                      field=c["field"], igrf_degree=c["igrf_degree"], epoch=epoch,
                                      raan_deg=float(raan_deg), arg_lat_deg=c["arg_lat_deg"])

    def reference_period(self) -> float:
        """Nominal period of the undispersed orbit (epoch_min, raan_min_deg): the run length is
        ``orbits`` of it for every run, whatever its own orbit."""
        if self.campaign["environment"] == "full":
            return nominal_orbit_period(self.p, self.env_options(self.epoch_min, self.dispersions["raan_min_deg"]))
        return float(self.p.orbit_period)

    def steps(self) -> int:
        return int(round(self.campaign["orbits"] * self.reference_period() / self.campaign["ts"]))

    def record_every(self) -> int:
        return max(1, int(round(self.campaign["history_step"] / self.campaign["ts"])))


def _resolve(path: str, spec_path: Path) -> Path:
    """A file named in the spec: absolute, else relative to the current directory, the spec's
    directory, then the repository root."""
    p = Path(path).expanduser()
    if p.is_absolute():
        return p
    for base in (Path.cwd(), spec_path.parent, ROOT):
        if (base / p).is_file():
            return base / p
    return p


def load_spec(path) -> CampaignSpec:
    """Read and validate a campaign spec; load its spacecraft and gains files.

    Raises ConfigError naming the file, the field and the fix (unknown keys and sections too).
    """
    path = Path(path)
    raw = load_user_yaml(path, "expected a campaign spec")  # missing, loop, not UTF-8, malformed, duplicate key
    if not isinstance(raw, dict):
        raise ConfigError(path, None, f"expected a mapping with sections {', '.join(SECTIONS)}")
    for key in raw:
        if key not in SECTIONS and key != "faults":
            raise ConfigError(path, key, f"unknown section; expected {', '.join(SECTIONS)} or faults")
    values = {}
    for name, fields in SECTIONS.items():
        sec = raw.get(name) or {}
        if not isinstance(sec, dict):
            raise ConfigError(path, name, "expected a mapping of fields")
        known = {f.name for f in fields}
        for key in sec:
            if key not in known:
                raise ConfigError(path, f"{name}.{key}", f"unknown field; expected one of {', '.join(sorted(known))}")
        sec = dict(sec)
        if name == "campaign" and isinstance(sec.get("gains"), list):
            gl = sec["gains"]
            if not gl or any(not isinstance(g, str) for g in gl):
                raise ConfigError(path, "campaign.gains", f"expected a file name or a list of file names, got {gl!r}")
            sec["gains"] = gl[0]
            values[name] = parse(sec, fields, path)
            values[name]["gains"] = list(gl)
        else:
            values[name] = parse(sec, fields, path)
    c, d = values["campaign"], values["dispersions"]
    if isinstance(c["gains"], str):
        c["gains"] = [c["gains"]]
    from ..design.field import FIELD_MODELS

    if c["field"] != "igrf" and c["field"] not in FIELD_MODELS:
        raise ConfigError(path, "campaign.field", f"expected igrf or one of {', '.join(FIELD_MODELS)}, got {c['field']!r}")
    sc = _resolve(c["spacecraft"], path)
    if not sc.is_file():
        raise ConfigError(path, "campaign.spacecraft", f"file not found: {c['spacecraft']}")
    p = load_spacecraft(sc)
    e0 = parse_epoch(d["epoch_min"], path, "dispersions.epoch_min") if d["epoch_min"] else p.epoch
    e1 = parse_epoch(d["epoch_max"], path, "dispersions.epoch_max") if d["epoch_max"] else e0
    if e1 < e0:
        raise ConfigError(path, "dispersions.epoch_max", f"must not precede epoch_min ({e0.isoformat()})")
    if c["arg_lat_deg"] is None:
        c["arg_lat_deg"] = float(p.arg_lat_deg)
    if d["raan_min_deg"] is None:
        d["raan_min_deg"] = float(p.raan_deg)
    if d["raan_max_deg"] is None:
        d["raan_max_deg"] = d["raan_min_deg"]
    if d["raan_max_deg"] < d["raan_min_deg"]:
        raise ConfigError(path, "dispersions.raan_max_deg", f"must be >= raan_min_deg ({d['raan_min_deg']:g})")
    if d["dipole_limit_max"] is None:
        d["dipole_limit_max"] = d["dipole_limit_min"]
    if d["dipole_limit_max"] < d["dipole_limit_min"]:
        raise ConfigError(path, "dispersions.dipole_limit_max", f"must be >= dipole_limit_min ({d['dipole_limit_min']:g})")
    if d["attitude_max_deg"] > 180.0:
        raise ConfigError(path, "dispersions.attitude_max_deg", f"expected at most 180, got {d['attitude_max_deg']:g}")
    if np.any(3.0 * d["inertia_rel_std"] >= 1.0):
        raise ConfigError(path, "dispersions.inertia_rel_std", "expected < 1/3 (3-sigma inertia must stay positive)")
    if raw.get("modes") and not c["modes"]:
        raise ConfigError(path, "modes", "a modes section needs campaign.modes: true")
    check_modes(values["modes"], path)
    if raw.get("estimator") and c["attitude"] != "estimator":
        raise ConfigError(path, "estimator", "an estimator section needs campaign.attitude: estimator")
    Torquers.from_values(values["torquers"]).check(c["ts"], f"{path}: torquers")
    faults = _faults(raw.get("faults"), path, c["orbits"] * p.orbit_period)
    Ks, files = [], []
    for g in c["gains"]:
        gp = _resolve(g, path)
        if not gp.is_file():
            raise ConfigError(path, "campaign.gains", f"file not found: {g}")
        Ks.append(load_gains(gp).K)
        files.append(str(g))
    return CampaignSpec(str(path), c, d, values["criteria"], files, np.array(Ks), p, e0, e1, raw, values["modes"],
                        values["estimator"], values["torquers"], faults)


def _faults(items, path, end: float) -> tuple:
    """Section ``faults`` (a list; None: none): each entry validated, of a kind the batch flies, starting before the
    run's end (its nominal orbits)."""
    faults = fl.from_list(items, f"{path}: faults")
    for i, f in enumerate(faults):
        if f.kind in NOT_BATCHED:
            raise ConfigError(path, f"faults[{i}].kind", f"{f.kind} is flown by magtune sil and the offline mode loop, "
                                                         f"not by campaigns; use one of {', '.join(FAULT_CODE)}")
    fl.check_times(faults, end, f"{path}: faults")
    return faults


# --- per-run parameters ------------------------------------------------------------------------
def draw_run(spec: CampaignSpec, i: int) -> dict:
    """The dispersed parameters of run ``i``: a function of (seed, i) only (module docstring)."""
    d = spec.dispersions
    rng = np.random.default_rng([spec.seed, int(i)])
    z = rng.standard_normal(3)
    e = np.clip(d["inertia_rel_std"] * z, -3.0 * d["inertia_rel_std"], 3.0 * d["inertia_rel_std"])
    inertia = np.asarray(spec.p.inertia, dtype=float).reshape(3) * (1.0 + e)
    mres = d["residual_dipole_mean"] + d["residual_dipole_std"] * rng.standard_normal(3)
    axis = rng.standard_normal(3)
    axis /= np.linalg.norm(axis)
    angle = math.radians(d["attitude_max_deg"]) * rng.uniform()
    q0 = np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * axis])
    dw0 = d["rate_mean"] + d["rate_max"] * rng.uniform(-1.0, 1.0, 3)
    span = (spec.epoch_max - spec.epoch_min).total_seconds()
    epoch_offset = span * rng.uniform()
    raan = d["raan_min_deg"] + (d["raan_max_deg"] - d["raan_min_deg"]) * rng.uniform()
    limit = d["dipole_limit_min"] + (d["dipole_limit_max"] - d["dipole_limit_min"]) * rng.uniform()
    mag_bias = d["mag_bias_std"] * rng.standard_normal(3)
    gyro_bias = d["gyro_bias_std"] * rng.standard_normal(3)
    # drawn last (always), so the draws above are those of a spec without it: a uniform rotation is a
    # normalized 4-D standard normal (Shoemake 1992; scipy's Rotation.random draws it so)
    qu = rng.standard_normal(4)
    if d["attitude_uniform"]:
        q0 = qu / np.linalg.norm(qu)
        q0 = -q0 if q0[0] < 0 else q0
        angle = 2.0 * math.acos(min(q0[0], 1.0))
        axis = q0[1:] / (np.linalg.norm(q0[1:]) or 1.0)
    return dict(run=int(i), inertia=inertia, residual_dipole=mres, attitude_angle_deg=math.degrees(angle),
                attitude_axis=axis, q0=q0, dw0=dw0, epoch=spec.epoch_min + timedelta(seconds=epoch_offset),
                epoch_offset_s=epoch_offset, raan_deg=raan, dipole_limit=limit, mag_bias=mag_bias,
                gyro_bias=gyro_bias, noise_seed=[spec.seed, int(i), 1])


def _batch_runs(spec: CampaignSpec, draws: list, gains_index: list) -> BatchRuns:
    d, c = spec.dispersions, spec.campaign
    n = len(draws)
    full = c["environment"] == "full"
    sensors = SensorNoise(np.full(n, d["mag_noise_std"]), np.array([r["mag_bias"] for r in draws]),
                          np.full(n, d["gyro_noise_std"]), np.array([r["gyro_bias"] for r in draws]),
                          np.full(n, d["attitude_noise_std"]), [r["noise_seed"] for r in draws],
                          gyro_arw=np.full(n, d["gyro_arw"]), gyro_rrw=np.full(n, d["gyro_rrw"]))
    return BatchRuns(K=spec.K[np.asarray(gains_index)], inertia=np.array([r["inertia"] for r in draws]),
                     residual_dipole=np.array([r["residual_dipole"] for r in draws]),
                     dipole_limit=np.array([r["dipole_limit"] for r in draws]),
                     q0=np.array([r["q0"] for r in draws]), dw0=np.array([r["dw0"] for r in draws]),
                     p=spec.p, environment=c["environment"],
                     env_options=[spec.env_options(r["epoch"], r["raan_deg"]) for r in draws] if full else None,
                     sensors=sensors, min_field=c["min_field"])


def run_figures(t, err_deg, m_norm, orbit_period: float, criteria: dict, saturated=None) -> dict:
    """Figures of merit of one run from its pointing error and |m| at every controller instant.

    The steady-state window is ``t >= max_settling_orbits * T`` (the instant by which the
    criteria require the run to have settled, the same for every run, so a run that settles
    late is not rewarded with a shorter window; the paper's RMS window starts at 1 T).

    Returns
    -------
    dict
        settling_time [s] (first instant after which the error stays below
        ``settle_threshold_deg``; nan: never), max and RMS pointing error in the steady-state
        window [deg] (nan if the run is shorter), final pointing error [deg], peak and RMS |m|
        over the run [A m^2]; with ``saturated`` (bool per instant), steady_saturation_fraction:
        the fraction of saturated instants in the steady-state window (nan if the run is shorter).
    """
    t, err, mn = np.asarray(t), np.asarray(err_deg), np.asarray(m_norm)
    ts_ = settling_time(t, err, criteria["settle_threshold_deg"])
    after = t >= criteria["max_settling_orbits"] * orbit_period
    steady = dict() if saturated is None else dict(
        steady_saturation_fraction=float(np.mean(np.asarray(saturated)[after])) if after.any() else math.nan)
    return dict(steady, settling_time=ts_, max_pointing_deg=float(err[after].max()) if after.any() else math.nan,
                rms_pointing_deg=float(np.sqrt(np.mean(err[after] ** 2))) if after.any() else math.nan,
                final_pointing_deg=float(err[-1]), peak_dipole=float(mn.max()),
                rms_dipole=float(np.sqrt(np.mean(mn**2))))


def deployment_figures(t, err_deg, mode_codes, criteria: dict) -> dict:
    """Time to settled pointing of one deployment from its mode and true pointing error at every instant.

    Settled pointing: the first instant from which the run stays in POINTING with the error below
    ``settle_threshold_deg`` to the end (nan: the run does not end so).

    Returns
    -------
    dict
        settled_time [s] (nan: never), final_mode (name), reached_pointing (POINTING entered at some instant).
    """
    t, err, code = np.asarray(t), np.asarray(err_deg), np.asarray(mode_codes)
    pnt = MODES.index(POINTING)
    good = (code == pnt) & (err < criteria["settle_threshold_deg"])
    bad = np.nonzero(~good)[0]
    settled = math.nan if not good[-1] else float(t[bad[-1] + 1] if bad.size else t[0])
    return dict(settled_time=settled, final_mode=MODES[int(code[-1])], reached_pointing=bool(np.any(code == pnt)))


def estimation_figures(t, err, sigma, nees, orbit_period: float, criteria: dict) -> dict:
    """Estimation figures of one run over the steady-state window ``t >= max_settling_orbits T`` (the pointing
    figures' window): RMS error per body axis [deg], fraction inside 3 sigma per axis, mean NEES.

    Returns
    -------
    dict
        est_rms_{x,y,z}_deg, est_inside_3sigma_{x,y,z}, est_nees_mean (nan: no estimate in the window).
    """
    after = (np.asarray(t) >= criteria["max_settling_orbits"] * orbit_period) & np.isfinite(np.asarray(nees))
    e, s = np.asarray(err, dtype=float)[after], np.asarray(sigma, dtype=float)[after]
    out = {}
    for i, a in enumerate("xyz"):
        out[f"est_rms_{a}_deg"] = math.degrees(float(np.sqrt(np.mean(e[:, i] ** 2)))) if after.any() else math.nan
        out[f"est_inside_3sigma_{a}"] = float(np.mean(np.abs(e[:, i]) <= 3 * s[:, i])) if after.any() else math.nan
    out["est_nees_mean"] = float(np.mean(np.asarray(nees, dtype=float)[after])) if after.any() else math.nan
    return out


def verdict(row: dict, criteria: dict, orbit_period: float) -> tuple[bool, str]:
    """(pass, reasons) of one run against the spec's criteria (a deployment: also reached and settled POINTING)."""
    if row["status"] != "ok":
        return False, row["status"]
    why = []
    if "settled_time" in row:  # a deployment campaign
        lim = criteria["max_deployment_orbits"]
        if not row["reached_pointing"]:
            why.append("never reached POINTING")
        elif not np.isfinite(row["settled_time"]):
            why.append(f"not settled in POINTING (final mode {row['final_mode']})")
        elif lim is not None and row["settled_time"] > lim * orbit_period:
            why.append(f"settled pointing at {row['settled_time']:.0f} s > {lim:g} orbits")
    if not np.isfinite(row["settling_time"]):
        why.append(f"never below {criteria['settle_threshold_deg']:g} deg")
    elif row["settling_time"] > criteria["max_settling_orbits"] * orbit_period:
        why.append(f"settling {row['settling_time']:.0f} s > {criteria['max_settling_orbits']:g} orbits")
    for key, lim in (("max_pointing_deg", "max_pointing_deg"), ("rms_pointing_deg", "max_rms_pointing_deg"),
                     ("peak_dipole", "max_peak_dipole"), ("saturation_fraction", "max_saturation_fraction"),
                     ("steady_saturation_fraction", "max_steady_saturation_fraction")):
        if criteria[lim] is not None and np.isfinite(row[key]) and row[key] > criteria[lim]:
            why.append(f"{key} {row[key]:.4g} > {criteria[lim]:g}")
    return not why, "; ".join(why)


def _param_columns(r: dict) -> dict:
    out = dict(run=r["run"], attitude_angle_deg=r["attitude_angle_deg"], epoch=r["epoch"].isoformat(),
               epoch_offset_s=r["epoch_offset_s"], raan_deg=r["raan_deg"], dipole_limit=r["dipole_limit"])
    for name, ax in (("inertia", "xyz"), ("residual_dipole", "xyz"), ("dw0", "xyz"), ("mag_bias", "xyz"),
                     ("gyro_bias", "xyz"), ("q0", "0123")):
        for k, a in enumerate(ax):
            out[f"{name}_{a}"] = float(r[name][k])
    return out


def _simulate_rows(spec: CampaignSpec, jobs: list, steps: int, record_every: int):
    """Simulate ``jobs`` [(gains index, run index)] as one batch; rows + downsampled histories."""
    draws = [draw_run(spec, i) for _, i in jobs]
    runs = _batch_runs(spec, draws, [g for g, _ in jobs])
    rule = spec.substeps
    res = simulate_batch(runs, ts=spec.campaign["ts"], steps=steps, substeps=rule.fewest, max_substeps=rule.most,
                         record_every=record_every, full_series=True, modes=spec.batch_modes(),
                         estimator=spec.batch_estimator(), torquers=spec.batch_torquers(), faults=spec.faults)
    t_all = np.arange(steps + 1) * spec.campaign["ts"]
    torquer = None
    if res.torquer_inputs is not None:  # the torquer watch replayed over the recorded inputs, then the inputs dropped
        ts = spec.campaign["ts"]
        torquer = replay(res.torquer_inputs, watch_params(spec.batch_estimator(), spec.p, ts,
                                                          on_fraction=spec.batch_torquers().on_fraction(ts)))
        res.torquer_inputs = None
    rows = []
    for b, ((g, i), r) in enumerate(zip(jobs, draws)):
        row = dict(_param_columns(r), gains=spec.gains_files[g], gains_index=g, orbit_period=float(res.orbit_period[b]))
        row.update(run_figures(t_all, res.pointing_deg[b], res.m_norm[b], res.orbit_period[b], spec.criteria,
                               res.saturated[b]))
        row.update(saturation_fraction=res.saturated_steps[b] / (steps + 1),
                   weak_field_fraction=res.weak_field_steps[b] / (steps + 1),
                   status="diverged" if res.diverged[b] else "ok", error="")
        if res.mode is not None:
            row.update(detumble_time=float(res.detumble_time[b]), pointing_time=float(res.pointing_time[b]),
                       transitions=int(res.transitions[b]),
                       **deployment_figures(t_all, res.pointing_deg[b], res.mode[b], spec.criteria))
        if res.est_error is not None:
            row.update(estimation_figures(t_all, res.est_error[b], res.est_sigma[b], res.est_nees[b], res.orbit_period[b],
                                          spec.criteria), est_fix_time=float(t_all[res.est_k0[b]]) if res.est_k0[b] >= 0
                       else math.nan, est_mag_rejected=int(res.est_counts[b, 1]), est_sun_rejected=int(res.est_counts[b, 3]))
        if res.fdir_code is not None:  # the sensor watch: the first unit named, when, how many verdicts
            row.update(fdir_unit=FDIR_UNITS.get(int(res.fdir_code[b]), ""), fdir_time=float(res.fdir_time[b]),
                       fdir_verdicts=int(res.fdir_count[b]))
        if torquer is not None:
            row.update(zip(TORQUER_COLUMNS, (torquer.unit(b), float(torquer.time[b]), str(torquer.kind[b]),
                                             int(torquer.verdicts[b]), *torquer.axis_time[b].tolist(),
                                             *(torquer.axis_kind(b, a) for a in range(3)))))
        rows.append(row)
    hist = dict(t=res.t.astype(np.float32), pointing_deg=res.pointing_deg[:, res.record_index].astype(np.float32),
                dipole=np.linalg.norm(res.m, axis=2).astype(np.float32),
                rate_error=np.linalg.norm(res.w - np.array([0.0, 0.0, -1.0])[None, None, :]
                                          * (2 * np.pi / res.orbit_period)[:, None, None], axis=2).astype(np.float32))
    return rows, hist


def _failed_row(spec: CampaignSpec, g: int, i: int, exc: BaseException) -> dict:
    try:
        params = _param_columns(draw_run(spec, i))
    except Exception:  # noqa: BLE001 - the row must exist even if drawing failed
        params = dict(run=int(i))
    row = dict(params, gains=spec.gains_files[g], gains_index=g, orbit_period=math.nan, status="failed",
               error=f"{type(exc).__name__}: {exc}"[:500])
    row.update({k: math.nan for k, _ in FIGURES})
    if spec.campaign["modes"]:
        row.update({k: math.nan for k, _ in MODE_FIGURES}, transitions=-1, final_mode="", reached_pointing=False)
    if spec.campaign["attitude"] == "estimator":
        row.update({k: math.nan for k, _ in ESTIMATION_FIGURES}, est_mag_rejected=-1, est_sun_rejected=-1)
        if spec.batch_estimator().sensor_watch:  # the columns of _rows' sensor-watch verdict, none reached
            row.update(fdir_unit="", fdir_time=math.nan, fdir_verdicts=-1)
        if spec.estimator.get("torquer_watch"):
            row.update(zip(TORQUER_COLUMNS, ("", math.nan, "", -1) + (math.nan,) * 3 + ("",) * 3))
    return row


def run_batch(spec: CampaignSpec, jobs: list, steps: int, record_every: int) -> dict:
    """One Dask task: the runs ``jobs`` [(gains index, run index)] advanced together.

    A batch that raises is re-run one run at a time, so one bad run is reported as failed
    (with its message) without losing the others. Returns ``{"rows", "hist", "jobs", "wall", "cpu"}``
(``cpu``: the task's process CPU time [s], what sizing a cluster needs, independent of the load).
    """
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        rows, hist = _simulate_rows(spec, jobs, steps, record_every)
        keep = list(range(len(jobs)))
    except Exception:  # noqa: BLE001 - isolate the culprit run(s) below
        rows, parts, keep = [], [], []
        for k, (g, i) in enumerate(jobs):
            try:
                r, h = _simulate_rows(spec, [(g, i)], steps, record_every)
                rows += r
                parts.append(h)
                keep.append(k)
            except Exception as exc:  # noqa: BLE001 - reported in the run's row
                rows.append(_failed_row(spec, g, i, exc))
        hist = None
        if parts:
            hist = dict(t=parts[0]["t"], **{key: np.concatenate([h[key] for h in parts])
                                            for key in ("pointing_deg", "dipole", "rate_error")})
    for row in rows:
        ok, why = verdict(row, spec.criteria, row["orbit_period"])
        row["passed"], row["fail_reasons"] = ok, why
    return dict(rows=rows, hist=hist, jobs=[jobs[k] for k in keep], wall=time.perf_counter() - t0,
                cpu=time.process_time() - c0)


# --- execution -----------------------------------------------------------------------------------
#: Dask's ``retries=`` of every task: a task that raised (not a run: run_batch keeps a run's own
#: exception in its row) is re-run by the scheduler up to this many more times.
TASK_RETRIES = 2
#: How often the client resubmits a batch whose task was lost (KilledWorker after its workers
#: died, cancelled): after that its runs are reported failed with the last error.
RESUBMITS = 2

def plan(spec: CampaignSpec, runs: int) -> list:
    """Batches of jobs [(gains index, run index)]: consecutive run indices, one gains file each."""
    bs = int(spec.campaign["batch_size"])
    out = []
    for g in range(len(spec.gains_files)):
        for a in range(0, runs, bs):
            out.append([(g, i) for i in range(a, min(a + bs, runs))])
    return out


def run_campaign(spec: CampaignSpec, runs: int, out, *, scheduler: str | None = None, workers: int | None = None,
                 progress: bool = True, dashboard: bool = False, tls: cluster.TlsFiles | None = None) -> dict:
    """Run the campaign and write DIR (module docstring); returns the ``campaign.json`` content.

    ``scheduler``: None (a closed LocalCluster of ``workers`` processes, default one per core,
    one thread each, :func:`.cluster.local_cluster`; ``dashboard``: serve its dashboard on
    127.0.0.1:8787), ``"tls://HOST:PORT"`` (an existing cluster, with ``tls`` or the Dask
    configuration's TLS credentials), ``"tcp://HOST:PORT"`` (an existing unauthenticated
    cluster) or ``"synchronous"`` (in this process, no Dask: debugging and the reference of
    the tests). Every batch task carries the spec by value (nothing a worker's death can lose);
    lost tasks are retried (:data:`TASK_RETRIES`, :data:`RESUBMITS`).
    """
    out = Path(out)  # created only when there are results to write (a failed connection leaves nothing)
    steps, every = spec.steps(), spec.record_every()
    batches = plan(spec, runs)
    total = sum(len(b) for b in batches)
    t0 = time.perf_counter()
    bar = _progress(total, progress)
    results, info = [], {}
    try:
        if scheduler == "synchronous":
            info = dict(scheduler="synchronous", workers=1)
            for j, jobs in enumerate(batches):
                results.append((j, run_batch(spec, jobs, steps, every)))
                bar.update(len(jobs))
        else:
            workers = int(workers or os.cpu_count() or 1)
            with cluster.connect(scheduler, workers, dashboard=dashboard, tls=tls) as (client, info):
                if info.get("dashboard"):
                    bar.write(f"campaign: dashboard at {info['dashboard']}")
                results, more = _run_dask(client, spec, batches, steps, every, bar)
                info.update(more)
    finally:
        bar.close()
    wall = time.perf_counter() - t0
    return write_results(spec, runs, out, results, batches, dict(info, wall=wall, steps=steps, record_every=every))


def _progress(total: int, enabled: bool):
    from tqdm import tqdm

    return tqdm(total=total, unit="run", desc="campaign", disable=not enabled, smoothing=0.1)


def _lost_batch(spec: CampaignSpec, jobs: list, exc: BaseException) -> dict:
    """The result of a batch whose task never completed: every run failed with the task's error."""
    rows = [_failed_row(spec, g, i, exc) for g, i in jobs]
    for row in rows:
        row["passed"], row["fail_reasons"] = False, "failed"
    return dict(rows=rows, hist=None, jobs=[], wall=math.nan, cpu=math.nan)


def _run_dask(client, spec, batches, steps, every, bar):
    """Submit one task per batch, the spec passed by value in each (no scattered data: a dead
    worker cannot take it with it); collect as they complete. The scheduler re-runs a task whose
    worker died; a task that still ends in error (KilledWorker, cancelled, ...) is resubmitted up
    to :data:`RESUBMITS` times, then its runs are reported failed with the reason.
    Returns (results, info) with info the worker count and the number of resubmissions."""
    from distributed import as_completed

    nworkers = len(client.scheduler_info(n_workers=-1)["workers"])

    def submit(j):
        return client.submit(run_batch, spec, batches[j], steps, every, pure=False, retries=TASK_RETRIES)

    futures = {submit(j): j for j in range(len(batches))}
    attempts = dict.fromkeys(range(len(batches)), 0)
    results, resubmitted = [], 0
    pending = as_completed(list(futures))
    for fut in pending:
        j = futures.pop(fut)
        try:
            res = fut.result()
        except Exception as exc:  # noqa: BLE001 - a lost task: resubmit, then report its runs failed
            nf, err = None, exc
            if attempts[j] < RESUBMITS:
                attempts[j] += 1
                resubmitted += 1
                try:
                    nf = submit(j)
                except Exception as sub_exc:  # noqa: BLE001 - the client is gone: report, keep the others
                    err = sub_exc
            if nf is not None:
                futures[nf] = j
                pending.add(nf)
                continue
            res = _lost_batch(spec, batches[j], err)
        results.append((j, res))
        bar.update(len(batches[j]))
    return results, dict(workers=nworkers, resubmitted=resubmitted)


def write_results(spec: CampaignSpec, runs: int, out: Path, results: list, batches: list, info: dict) -> dict:
    """runs.parquet, histories/batch_*.npz, campaign.json, spec.yaml; returns the campaign.json content."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    (out / "histories").mkdir(parents=True, exist_ok=True)
    results = sorted(results, key=lambda r: r[0])
    rows = []
    for j, res in results:
        for row in res["rows"]:
            rows.append(dict(row, batch=j))
        if res["hist"] is not None:
            h = res["hist"]
            with atomic_output(out / "histories" / f"batch_{j:05d}.npz", "wb") as fh:
                np.savez_compressed(fh, run=np.array([i for _, i in res["jobs"]]),
                                    gains_index=np.array([g for g, _ in res["jobs"]]), **h)
    rows.sort(key=lambda r: (r["gains_index"], r["run"]))
    cols = {}
    for key in rows[0]:
        cols[key] = [r.get(key) for r in rows]
    with atomic_output(out / "runs.parquet", "wb") as fh:
        pq.write_table(pa.table(cols), fh)
    status = [r["status"] for r in rows]
    meta = dict(name=spec.campaign["name"], spec=str(spec.path), seed=spec.seed, runs=runs,
                total_runs=len(rows), gains=spec.gains_files, environment=spec.campaign["environment"],
                orbits=spec.campaign["orbits"], ts=spec.campaign["ts"], substeps=list(spec.substeps.levels),
                batch_size=spec.campaign["batch_size"], batches=len(batches),
                counts={s: status.count(s) for s in STATUSES}, passed=int(sum(bool(r["passed"]) for r in rows)),
                campaign=_plain(spec.campaign), dispersions=_plain(spec.dispersions), criteria=_plain(spec.criteria),
                **(dict(modes=_plain(spec.modes)) if spec.campaign["modes"] else {}),
                **(dict(torquers=_plain(spec.torquers)) if spec.raw.get("torquers") else {}),
                **(dict(faults=[f.spec for f in spec.faults]) if spec.faults else {}), **info)
    meta["failed_runs"] = [dict(run=int(r["run"]), gains=r["gains"], error=r.get("error", "")) for r in rows
                           if r["status"] == "failed"]
    meta["runs_per_second"] = len(rows) / info["wall"] if info.get("wall") else math.nan
    # CPU time of the tasks (load-independent): per run, and what a wall-clock rate would be on idle cores
    meta["task_cpu_s"] = float(np.nansum([res.get("cpu", math.nan) for _, res in results]))
    meta["cpu_s_per_run"] = meta["task_cpu_s"] / len(rows)
    atomic_write(out / "campaign.json", jsonout.dumps(meta, indent=1, default=str))
    atomic_write(out / "spec.yaml", yaml.safe_dump(spec.raw, sort_keys=False))
    return meta


def _plain(d: dict) -> dict:
    return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in d.items()}


def read_runs(out) -> dict:
    """runs.parquet as {column: numpy array}."""
    import pyarrow.parquet as pq

    t = pq.read_table(Path(out) / "runs.parquet")
    return {name: t.column(name).to_numpy(zero_copy_only=False) for name in t.column_names}


def read_histories(out) -> dict:
    """All histories/batch_*.npz concatenated, sorted by (gains index, run)."""
    parts = [np.load(f) for f in sorted((Path(out) / "histories").glob("batch_*.npz"))]
    if not parts:
        return {}
    h = {k: np.concatenate([p[k] for p in parts]) for k in ("run", "gains_index", "pointing_deg", "dipole", "rate_error")}
    h["t"] = parts[0]["t"]
    order = np.lexsort((h["run"], h["gains_index"]))
    return {k: (v if k == "t" else v[order]) for k, v in h.items()}


def with_criteria(spec: CampaignSpec, **criteria) -> CampaignSpec:
    """A copy of ``spec`` with some criteria replaced (tests, what-if reports)."""
    return replace(spec, criteria=dict(spec.criteria, **criteria))
