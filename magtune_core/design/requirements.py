"""The flight's requirements as part of the tuning problem: one validated design spec.

J (paper eq. 21) is the soft goal; the hard requirements are what the flight needs and J does
not see (docs/requirements.md):

* ``sampling``: the sample-and-hold loop (:mod:`.sampled`) stays stable with the gain times every
  k in [1, ``gain_margin``] at every admissible sample period of [ts_min, ts_max] (paper section 5:
  no significant degradation up to Ts = 20 s). Near the nutation limit stability is not monotone in
  k, so the tuner's screen checks ``check_periods`` periods at both ends of the margin (the top end
  with the guard band) plus the (period, scale) points a certificate found unstable; the final gain
  is certified by :func:`.hold_certificate.certify_hold` (every admissible period, k step
  ``scale_step``, ``guard`` past the margin), and a failing certificate adds its unstable points
  to the screen and resumes the search (``design.pipeline``);
* ``dipole``: the worst-case peak commanded dipole per axis of the held loop at ts_min and ts_max
  (:mod:`.dipole`) from the requirement's initial states and residual dipoles stays within the
  budget ``budget_fraction`` x ``limit`` (default: the spacecraft file's ``dipole_limit``);
* ``pointing``: what ``magtune verify`` accepts a gain by (Monte Carlo in the full environment).

The same file is read by ``tune``, ``front``, ``analyze`` and ``verify`` (``config/design.yaml``).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import yaml

from ..base.errors import ConfigError
from ..base.schema import Field, parse
from .dipole import DipoleCase, peak_dipole
from .hold_certificate import GUARD, STEP, HoldCertificate, certify_hold
from .model import AttitudeLTP
from .node_params import INITIAL_RATE_ERROR
from .sampled import SampledLoop, hold_gain_margin

SAMPLING_FIELDS = (
    Field("ts_min", "float", "shortest sample period the flight computer may run [s] (the gains' Ts)", 1.0,
          positive=True, unit="s"),
    Field("ts_max", "float", "longest sample period the gains must hold at [s]", 30.0, positive=True, unit="s"),
    Field("gain_margin", "float", "sample-and-hold gain margin at every Ts of the range (factor; 0: no hold "
          "requirement, the paper's unconstrained problem)", 4.0, nonnegative=True),
    Field("max_multiplier", "float", "largest |characteristic multiplier| of the held loop with the gain over one "
          "orbit, at every Ts of the range (the slowest mode's decay per orbit; 1: stable only, the default)", 1.0,
          positive=True, bounds=(0.0, 1.0)),
    Field("check_periods", "int", "sample periods the tuner checks (geometric in [ts_min, ts_max])", 8, positive=True),
    Field("scan_periods", "int", "sample periods of the quick scan between search rounds (the certificate checks "
          "every admissible period)", 96, positive=True),
    Field("scale_step", "float", "largest step of the certificate's grid of gain scales in [1, gain_margin] (the "
          "resolution an instability island is found at)", STEP, positive=True, bounds=(0.0, 0.05)),
    Field("guard", "float", "relative guard band past gain_margin that must be stable too (above the eigenvalue's "
          "numerical error near the boundary, ~5e-4)", GUARD, nonnegative=True, bounds=(0.0, 0.1)),
)
DIPOLE_FIELDS = (
    Field("limit", "float", "per-axis dipole the torquers deliver [A m^2] (default or null: the spacecraft file's "
          "dipole_limit)", None, positive=True, unit="A m^2", nullable=True),
    Field("budget_fraction", "float", "fraction of the limit the linear closed loop may command (0: no dipole "
          "requirement); the rest is left to noise and unmodelled torques", 0.8, nonnegative=True),
    Field("rate_nominal", "float[]", "initial rate error dw(0), nominal [rad/s]", INITIAL_RATE_ERROR, size=3),
    Field("rate_radius", "float[]", "initial rate error: +- per axis [rad/s]", (5e-4, 5e-4, 5e-4), size=3,
          nonnegative=True),
    Field("attitude_max_deg", "float", "initial attitude error: any rotation up to this angle [deg] (0: the paper's dq(0) = 0; an "
          "acquisition from a large error saturates briefly, which verify's saturation fraction bounds)", 0.0,
          nonnegative=True, bounds=(0.0, 90.0)),
    Field("residual_nominal", "float[]", "residual dipole, nominal per body axis [A m^2]", (1.0, 1.0, 1.0), size=3),
    Field("residual_radius", "float[]", "residual dipole: +- per axis [A m^2] (3 sigma of the example dispersion)",
          (0.9, 0.9, 0.9), size=3, nonnegative=True),
    Field("horizon_orbits", "float", "horizon of the peak check [orbits]", 2.0, positive=True),
)
POINTING_FIELDS = (
    Field("settle_threshold_deg", "float", "pointing error below which a run counts as settled [deg]", 2.0,
          positive=True),
    Field("max_settling_orbits", "float", "settle within this many orbits", 2.0, positive=True),
    Field("max_pointing_deg", "float", "peak pointing error after settling [deg]", 3.0, positive=True),
    Field("max_rms_pointing_deg", "float", "RMS pointing error after settling [deg]", 1.0, positive=True),
    Field("max_saturation_fraction", "float", "fraction of controller steps with a saturated axis after settling "
          "(t >= max_settling_orbits T)", 0.01, nonnegative=True),
    Field("max_total_saturation_fraction", "float", "... over the whole run, acquisition included (null: none)",
          None, nonnegative=True, nullable=True),
    Field("pass_fraction", "float", "fraction of Monte Carlo runs that must meet every pointing requirement", 0.99,
          positive=True, bounds=(0.0, 1.0)),
)
SECTIONS = {"sampling": SAMPLING_FIELDS, "dipole": DIPOLE_FIELDS, "pointing": POINTING_FIELDS}


@dataclass(frozen=True)
class Check:
    """One hard requirement evaluated on one gain: ``value`` against ``limit`` (``kind`` says which side)."""

    name: str
    value: float
    limit: float
    kind: str  # ">=": value must be at least limit (a margin); "<=": at most (a peak)

    @property
    def ok(self) -> bool:
        """Whether the requirement holds.

        Returns
        -------
        bool
            value >= limit for kind ">=", value <= limit otherwise.
        """
        return bool(self.value >= self.limit) if self.kind == ">=" else bool(self.value <= self.limit)

    @property
    def slack(self) -> float:
        """Relative distance to the limit: > 0 met, < 0 violated (-0.1: 10 % short).

        Returns
        -------
        float
            value / limit - 1 (">=") or 1 - value / limit ("<="); +-inf for a non-finite value.
        """
        if not np.isfinite(self.value):
            return np.inf if (self.kind == ">=") == (self.value > 0) else -np.inf
        return (self.value / self.limit - 1.0) if self.kind == ">=" else (1.0 - self.value / self.limit)

    def __str__(self) -> str:
        return f"{self.name} {self.value:.4g} {'>=' if self.kind == '>=' else '<='} {self.limit:.4g}"


@dataclass(frozen=True)
class Requirements:
    """A validated design spec (module docstring): its three sections' values."""

    sampling: dict
    dipole: dict
    pointing: dict
    dipole_limit: float  # the resolved per-axis limit [A m^2]
    source: str = "defaults"
    extra_periods: tuple = field(default=())  # periods added by the dense scan (cutting planes)
    extra_points: tuple = field(default=())   # (period, scale) pairs a certificate found unstable (cutting planes)
    #: the hardware file the limit was resolved against (design.hardware.Hardware; verify flies its sensors and
    #: torquer range), None without one
    hardware: object = field(default=None, compare=False)

    @classmethod
    def from_mapping(cls, raw: dict | None, spacecraft_limit: float, where="design spec") -> "Requirements":
        """Validate a design spec mapping (sections ``sampling``, ``dipole``, ``pointing``); ConfigError if bad.

        Parameters
        ----------
        raw : dict or None
            Section name -> mapping of fields; None or empty: every default.
        spacecraft_limit : float
            Per-axis dipole limit [A m^2] used when the ``dipole`` section gives no ``limit``.
        where : str
            File or context named in error messages (and stored as ``source``).

        Returns
        -------
        Requirements
            The validated sections and the resolved dipole limit.

        Raises
        ------
        ConfigError
            If ``raw`` is not a mapping, a section is unknown or not a mapping, a field is invalid,
            ts_max < ts_min, or 0 < gain_margin < 1.
        """
        raw = raw or {}
        if not isinstance(raw, dict):
            raise ConfigError(where, None, f"expected a mapping with sections {', '.join(SECTIONS)}")
        for key in raw:
            if key not in SECTIONS:
                raise ConfigError(where, str(key), f"unknown section; expected {', '.join(SECTIONS)}")
        vals = {}
        for name, fields in SECTIONS.items():
            sec = raw.get(name) or {}
            if not isinstance(sec, dict):
                raise ConfigError(where, name, "expected a mapping of fields")
            vals[name] = parse(sec, fields, where, allowed=())
        s = vals["sampling"]
        if s["ts_max"] < s["ts_min"]:
            raise ConfigError(where, "sampling.ts_max", f"must be >= ts_min ({s['ts_min']:g} s)")
        if 0 < s["gain_margin"] < 1:
            raise ConfigError(where, "sampling.gain_margin", f"expected 0 (none) or >= 1, got {s['gain_margin']:g}")
        limit = vals["dipole"]["limit"] or float(spacecraft_limit)
        return cls(vals["sampling"], vals["dipole"], vals["pointing"], float(limit), str(where))

    @property
    def ts(self) -> float:
        """The gains' sample period: the shortest of the range.

        Returns
        -------
        float
            ts_min [s].
        """
        return float(self.sampling["ts_min"])

    @property
    def gain_margin(self) -> float:
        """Required hold gain margin (0: none).

        Returns
        -------
        float
            The margin factor of the ``sampling`` section.
        """
        return float(self.sampling["gain_margin"])

    @property
    def max_multiplier(self) -> float:
        """Largest |characteristic multiplier| of the held loop with K (1: stability only); part of the
        hold requirement, so inactive when ``gain_margin`` is 0.

        Returns
        -------
        float
            max_multiplier of the ``sampling`` section, in (0, 1].
        """
        return float(self.sampling["max_multiplier"])

    @property
    def dipole_budget(self) -> float:
        """Per-axis dipole the linear loop may command [A m^2] (0: no dipole requirement).

        Returns
        -------
        float
            budget_fraction x dipole_limit [A m^2].
        """
        return float(self.dipole["budget_fraction"]) * self.dipole_limit

    @property
    def constrained(self) -> bool:
        """False for the paper's unconstrained problem (no hold, no dipole requirement).

        Returns
        -------
        bool
            True if a hold gain margin or a dipole budget is required.
        """
        return self.gain_margin > 0 or self.dipole_budget > 0

    def periods(self, points: int | None = None) -> np.ndarray:
        """The checked sample periods: geometric in [ts_min, ts_max] (``points``, default check_periods),
        plus the periods the dense scan added, ascending.

        Parameters
        ----------
        points : int or None
            Number of geometric periods; None: ``check_periods``.

        Returns
        -------
        ndarray (m,)
            Unique sample periods [s], ascending.
        """
        lo, hi = self.sampling["ts_min"], self.sampling["ts_max"]
        n = int(points or self.sampling["check_periods"])
        base = np.array([lo]) if hi == lo or n == 1 else np.geomspace(lo, hi, max(n, 2))
        return np.unique(np.concatenate([base, np.asarray(self.extra_periods, dtype=float)]))

    def with_periods(self, extra) -> "Requirements":
        """The same requirements with more checked periods (the dense scan's cutting planes).

        Parameters
        ----------
        extra : iterable of float
            Sample periods [s] to add.

        Returns
        -------
        Requirements
            A copy whose ``extra_periods`` are the sorted union of the old and the new.
        """
        return replace(self, extra_periods=tuple(sorted(set(self.extra_periods) | {float(t) for t in extra})))

    def with_points(self, points) -> "Requirements":
        """The same requirements with more (period, scale) points the screen checks (a certificate's
        unstable points: the cutting planes of an instability island between the margin's ends).

        Parameters
        ----------
        points : iterable of (float, float)
            (sample period [s], gain scale) pairs.

        Returns
        -------
        Requirements
            A copy whose ``extra_points`` are the sorted union of the old and the new.
        """
        new = {(float(t), float(k)) for t, k in points}
        return replace(self, extra_points=tuple(sorted(set(self.extra_points) | new)))

    @property
    def scale_top(self) -> float:
        """The largest gain scale that must be stable: gain_margin x (1 + guard).

        Returns
        -------
        float
            The top of the certificate's grid (0 without a hold requirement).
        """
        return self.gain_margin * (1.0 + float(self.sampling["guard"]))

    def certify(self, model: AttitudeLTP, K, workers: int = 2) -> HoldCertificate:
        """The hold requirement's certificate of one gain (:func:`.hold_certificate.certify_hold`).

        Parameters
        ----------
        model : AttitudeLTP
            Design model.
        K : array_like (3, 6)
            Gain.
        workers : int
            Threads scanning the periods.

        Returns
        -------
        HoldCertificate
            Every admissible period of [ts_min, ts_max], scales 1 .. gain_margin (1 + guard).

        Raises
        ------
        ValueError
            Without a hold requirement (gain_margin 0).
        """
        if not self.gain_margin:
            raise ValueError("no hold requirement to certify (gain_margin 0)")
        s = self.sampling
        return certify_hold(model, K, s["ts_min"], s["ts_max"], self.gain_margin, self.max_multiplier,
                            step=float(s["scale_step"]), guard=float(s["guard"]), workers=workers)

    def dipole_case(self) -> DipoleCase:
        """The initial states and residual dipoles of the budget (:class:`.dipole.DipoleCase`).

        Returns
        -------
        DipoleCase
            Rates, attitude ball, residual dipoles and horizon of the ``dipole`` section.
        """
        d = self.dipole
        return DipoleCase(tuple(d["rate_nominal"]), tuple(d["rate_radius"]), float(d["attitude_max_deg"]),
                          tuple(d["residual_nominal"]), tuple(d["residual_radius"]), float(d["horizon_orbits"]))

    def screen(self, model: AttitudeLTP) -> "FlightScreen":
        """The compiled checks of these requirements on one model (:class:`FlightScreen`).

        Parameters
        ----------
        model : AttitudeLTP
            Design model.

        Returns
        -------
        FlightScreen
            :meth:`FlightScreen.build` of ``model`` and these requirements.
        """
        return FlightScreen.build(model, self)

    def describe(self) -> str:
        """One line: what the tuner is asked (what a gains file's provenance records).

        Returns
        -------
        str
            The hold requirement (or "no hold requirement") and the dipole budget (or "no dipole budget").
        """
        s = self.sampling
        rho = f", |multiplier| <= {self.max_multiplier:g}" if self.max_multiplier < 1 else ""
        parts = [f"hold gain margin {s['gain_margin']:g}{rho} at Ts {s['ts_min']:g}-{s['ts_max']:g} s"
                 if self.gain_margin else "no hold requirement"]
        parts.append(f"peak |m_i| <= {self.dipole_budget:.4g} A m^2" if self.dipole_budget else "no dipole budget")
        return "; ".join(parts)


def spacecraft_dipole_limit(spacecraft_path) -> float:
    """The torquers' per-axis limit of a spacecraft file (its nodes' ``dipole_limit``, the weakest
    axis; the controller's default when the file gives none) [A m^2].

    Parameters
    ----------
    spacecraft_path : str or Path
        Spacecraft parameter file.

    Returns
    -------
    float
        Smallest per-axis ``dipole_limit`` [A m^2] (or the onboard default).
    """
    from ..base.paramfile import read_ros_params
    from ..onboard.params import DEFAULT_DIPOLE_LIMIT

    value = read_ros_params(spacecraft_path).get("dipole_limit", DEFAULT_DIPOLE_LIMIT)
    return float(np.min(np.asarray(value, dtype=float)))


def load_requirements(path, spacecraft_limit: float) -> Requirements:
    """Read and validate a design spec file (ConfigError naming the file and field).

    Parameters
    ----------
    path : str or Path
        Design spec file (YAML).
    spacecraft_limit : float
        Per-axis dipole limit [A m^2] used when the spec gives none.

    Returns
    -------
    Requirements
        The spec, its dipole limit resolved against ``spacecraft_limit``.

    Raises
    ------
    ConfigError
        If the file does not exist, is not valid YAML, or :meth:`Requirements.from_mapping` rejects it.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(path, None, "design spec not found")
    try:
        raw = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(path, None, f"not valid YAML ({str(exc).splitlines()[0]})") from None
    return Requirements.from_mapping(raw, spacecraft_limit, where=str(path))


@dataclass(frozen=True)
class FlightScreen:
    """The hard requirements of :class:`Requirements` compiled for one model: held loops at the
    checked periods (longest first: the cheapest and, for these loops, usually the binding one)
    and the dipole proxy's loops at ts_min and ts_max. Picklable (sent to the tuner's workers)."""

    loops: tuple          # SampledLoop per checked period, longest Ts first
    gain_margin: float
    max_multiplier: float
    dipole_loops: tuple   # SampledLoop at ts_min (and ts_max)
    case: DipoleCase
    budget: float
    top: float = 0.0      # the margin's top end checked: gain_margin (1 + guard); 0: gain_margin
    points: tuple = ()    # (SampledLoop, scales) of the cutting planes: rho(scale K) < 1 at each

    @classmethod
    def build(cls, model: AttitudeLTP, req: Requirements) -> "FlightScreen":
        """Interval maps of every checked period (:meth:`.sampled.SampledLoop.build`).

        Parameters
        ----------
        model : AttitudeLTP
            Design model.
        req : Requirements
            Requirements to compile.

        Returns
        -------
        FlightScreen
            Held loops at the checked periods (none without a gain margin) and at ts_min/ts_max (none without a budget).
        """
        loops = tuple(SampledLoop.build(model, t) for t in req.periods()[::-1]) if req.gain_margin else ()
        lo, hi = req.sampling["ts_min"], req.sampling["ts_max"]
        dl = tuple(SampledLoop.build(model, t) for t in sorted({lo, hi})) if req.dipole_budget else ()
        by_ts: dict = {}
        for t, k in (req.extra_points if req.gain_margin else ()):
            by_ts.setdefault(t, []).append(k)
        points = tuple((SampledLoop.build(model, t), np.array(sorted(ks))) for t, ks in sorted(by_ts.items()))
        return cls(loops, req.gain_margin, req.max_multiplier, dl, req.dipole_case(), req.dipole_budget,
                   req.scale_top, points)

    def __call__(self, Ks) -> np.ndarray:
        """Whether each gain meets every hard requirement (n,): hold margins, then the dipole budget.

        Returns
        -------
        ndarray of bool (n,)
        """
        Ks = np.asarray(Ks, dtype=float).reshape(-1, 3, 6)
        ok = np.ones(len(Ks), dtype=bool)
        for loop in self.loops:  # the margin's both ends (hold_ends)
            for g, rho in hold_ends(self.top or self.gain_margin, self.max_multiplier):
                if ok.any():
                    ok[ok] = loop.spectral_radius(g * Ks[ok]) < rho
        for loop, scales in self.points:  # the cutting planes: scales a certificate found unstable
            for g in scales:
                if ok.any():
                    ok[ok] = loop.spectral_radius(g * Ks[ok]) < 1.0
        for loop in self.dipole_loops:  # a gain may stop once above the budget: only the verdict is used
            if ok.any():
                ok[ok] = peak_dipole(loop, Ks[ok], self.case, stop_above=self.budget).max(axis=-1) <= self.budget
        return ok

    def checks(self, K, hold: bool = True) -> list:
        """Every hard requirement of one gain, with its value (what binds and by how much).

        Parameters
        ----------
        K : array_like (3, 6)
            Gain.
        hold : bool
            Include the hold checks (False: the dipole budget only).

        Returns
        -------
        list of Check
            the hold gain margin at each checked period (``>=`` gain_margin), the held loop's
            largest |multiplier| there (``<=`` max_multiplier) and the peak dipole per axis at
            each dipole period (``<=`` budget).
        """
        K = np.asarray(K, dtype=float).reshape(3, 6)
        loops = self.loops if hold else ()
        out = [Check(f"hold gain margin at Ts = {loop.ts:.4g} s", hold_gain_margin(loop, K), self.top or self.gain_margin,
                     ">=") for loop in loops]
        out += [Check(f"held-loop |multiplier| at Ts = {loop.ts:.4g} s", float(loop.spectral_radius(K[None])[0]),
                      self.max_multiplier, "<=") for loop in loops if self.max_multiplier < 1.0]
        for loop in self.dipole_loops:
            pk = peak_dipole(loop, K[None], self.case)[0]
            i = int(np.argmax(pk))
            out.append(Check(f"peak |m_{'xyz'[i]}| at Ts = {loop.ts:.4g} s [A m^2]", float(pk[i]), self.budget, "<="))
        return out


def scan_hold(model: AttitudeLTP, K, req: Requirements, points: int | None = None, cache: dict | None = None):
    """Dense scan of the sample-and-hold requirement for one gain: is the loop with the gain and with
    the gain times ``gain_margin`` stable at ``points`` periods (default scan_periods) of [ts_min,
    ts_max]? ``cache``: the loops already built for this model (:meth:`.sampled.SampledLoop.at`).

    Parameters
    ----------
    model : AttitudeLTP
        Design model.
    K : array_like (3, 6)
        Gain.
    req : Requirements
        Sampling requirements (range, margin, multiplier bound).
    points : int or None
        Number of scanned periods; None: ``scan_periods``.
    cache : dict or None
        {ts: SampledLoop} of this model, read and filled.

    Returns
    -------
    (ndarray, ndarray of bool)
        the scanned periods (the intervals actually used, T / round(T / Ts)) and whether each holds.
    """
    K = np.asarray(K, dtype=float).reshape(1, 3, 6)
    ts = req.periods(points or req.sampling["scan_periods"])
    loops = SampledLoop.at(model, ts, cache)
    return np.array([loop.ts for loop in loops]), np.array([held_margin_ok(loop, K, req.gain_margin, req.max_multiplier)
                                                            for loop in loops])


def tightest_period(model: AttitudeLTP, K, req: Requirements) -> float:
    """The scanned period where the hold margin from K up is smallest: where ``verify`` flies a gains file
    that records none (``hold_tightest_ts``), found in seconds instead of the certificate's minutes.

    Parameters
    ----------
    model : AttitudeLTP
        Design model.
    K : array_like (3, 6)
        Gain.
    req : Requirements
        Sampling requirements (range, ``scan_periods``).

    Returns
    -------
    float
        The interval actually used there, T / round(T / Ts) [s].
    """
    loops = SampledLoop.at(model, req.periods(req.sampling["scan_periods"]))
    margins = [hold_gain_margin(loop, np.asarray(K, dtype=float).reshape(3, 6)) for loop in loops]
    return float(loops[int(np.argmin(margins))].ts)


def hold_ends(gain_margin: float, max_multiplier: float = 1.0) -> tuple:
    """The hold requirement at one period as (scale, bound) pairs, rho(scale x K) < bound for each:
    the held loop stable with K x ``gain_margin`` and decaying by ``max_multiplier`` per orbit with K
    (both ends of the margin: near the nutation limit stability is not monotone in the gain's scale).

    Parameters
    ----------
    gain_margin : float
        Required gain margin (factor).
    max_multiplier : float
        Bound on rho(K) (1: stability only).

    Returns
    -------
    tuple of (float, float)
        ((gain_margin, 1.0), (1.0, max_multiplier)).
    """
    return ((float(gain_margin), 1.0), (1.0, float(max_multiplier)))


def held_radii(loop, K, gain_margin: float) -> np.ndarray:
    """The held loop's largest |multiplier| at the scales of :func:`hold_ends`, of one gain.

    Parameters
    ----------
    loop : SampledLoop
        Held loop of one model at one period.
    K : array_like (3, 6)
        Gain.
    gain_margin : float
        Required gain margin (factor).

    Returns
    -------
    ndarray (2,)
        rho(gain_margin x K), rho(K).
    """
    K = np.asarray(K, dtype=float).reshape(1, 3, 6)
    return loop.spectral_radius(np.concatenate([g * K for g, _ in hold_ends(gain_margin)]))


def held_margin_ok(loop, K, gain_margin: float, max_multiplier: float = 1.0) -> bool:
    """The hold requirement at one period (:func:`hold_ends`) for one gain.

    Parameters
    ----------
    loop : SampledLoop
        Held loop of one model at one period.
    K : array_like (3, 6)
        Gain.
    gain_margin : float
        Required gain margin (factor).
    max_multiplier : float
        Bound on rho(K).

    Returns
    -------
    bool
        True if rho(gain_margin K) < 1 and rho(K) < max_multiplier.
    """
    bounds = [b for _, b in hold_ends(gain_margin, max_multiplier)]
    return bool(np.all(held_radii(loop, K, gain_margin) < bounds))


def claim_contradictions(prov: dict) -> list:
    """What a gains file's own figures say against its claim ``requirements_met: true`` (empty: none).

    A certificate claims only what was proven: the hold requirement needs a hold certificate
    (:mod:`.hold_certificate`; files written before it checked the margin's two ends only) whose
    certified margin reaches the required one and whose grid found no multiplier >= 1, and the
    dipole proxy must be within the budget.

    Parameters
    ----------
    prov : dict
        A gains file's provenance.

    Returns
    -------
    list of str
        One line per contradiction, naming the field and the figure.
    """
    if prov.get("requirements_met") is not True:
        return []
    out = []
    need = float(prov.get("hold_gain_margin_required") or 0.0)
    if need:
        if "hold_certificate" not in prov:
            out.append("hold_certificate: missing (the claim was made on the margin's two ends only; re-certify "
                       "with magtune analyze --requirements --record, or re-tune)")
        low = prov.get("hold_margin_min")
        if low is not None and float(low) < need:
            out.append(f"hold_margin_min: {float(low):g} below hold_gain_margin_required {need:g}")
        top = prov.get("hold_rho_max")
        if top is not None and float(top) >= 1.0:
            out.append(f"hold_rho_max: {float(top):g} >= 1 (unstable somewhere on the certified grid)")
    peak, budget = prov.get("dipole_peak_proxy"), prov.get("dipole_budget")
    if peak is not None and budget and float(peak) > float(budget):
        out.append(f"dipole_peak_proxy: {float(peak):g} above dipole_budget {float(budget):g} A m^2")
    return out
