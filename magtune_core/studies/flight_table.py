"""The flight parameter table of a design: what the flight nodes fly, gathered once, written three ways.

:func:`build_table` gathers every parameter of the three flight nodes (``controller``,
``mode_manager``, ``attitude_estimator``) from layered sources, each value remembering where it came
from (lowest first): the schemas' defaults (``onboard/params.py``), the flight stack's settings
(:data:`FLIGHT_SETTINGS`: what ``magtune sil --modes --attitude estimator`` sets, the on-board models'
environment and the time origin at the spacecraft's epoch), the spacecraft file (its node sections),
an optional hardware file (``--hardware``: its torquers' limit and coupling for the controller, its
noise model for the estimator, :mod:`magtune_core.design.hardware`), the gains file (the controller's)
and an optional parameter file (``--params``). Every node's values are validated by its own schema.

Writers: :func:`parameter_file_text` (a ROS 2 parameter file the nodes load: ``/**`` the mission
data, ``/**/<node>`` each node's parameters), :func:`header_text` (a C99 header of ``static const``
data, doubles printed with 17 significant digits) and :func:`document` (a JSON document with a schema
version, provenance, source hashes and the SHA-256 of its canonical content, :func:`canonical_bytes`).
Format: docs/export.md.
"""
from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from ..base.errors import ConfigError
from ..base.paramfile import check_ros_params, load_ros_params, merge_ros_params, read_regular
from ..base.schema import parse
from ..design.gains import CONTROLLER_NODE, Gains
from ..design.hardware import check_spacecraft_agrees, load_hardware
from ..design.node_params import SIL_NODE_FIELDS
from ..design.params import SpacecraftParams, warn_tle
from ..onboard.modes import MODES
from ..onboard.params import check_modes
from ..ros.scenario import epoch_ns
from ..sim.flight_stack import resolved_bdot_gain

#: The JSON document's format name and version (docs/export.md: what a version change means).
FORMAT = "magtune-flight-table"
SCHEMA_VERSION = 1
#: The flight nodes, in the order they are written.
FLIGHT_NODES = ("controller", "mode_manager", "attitude_estimator")
#: Each flight node's schema (the gains file's three fields first for the controller).
NODE_FIELDS = {"controller": Gains.FIELDS + SIL_NODE_FIELDS["controller"],
               "mode_manager": SIL_NODE_FIELDS["mode_manager"],
               "attitude_estimator": SIL_NODE_FIELDS["attitude_estimator"]}
#: The mission data every flight node reads (the ``/**`` section).
MISSION_FIELDS = SpacecraftParams.FIELDS
#: Prefix of each section's names in the C header.
C_PREFIX = {"controller": "MAGTUNE_CTRL_", "mode_manager": "MAGTUNE_MODES_", "attitude_estimator": "MAGTUNE_EST_",
            "mission": "MAGTUNE_SC_"}
#: Source names (JSON ``source`` of each value).
DEFAULT, STACK, SPACECRAFT, HARDWARE, GAINS, PARAMS = ("default", "flight stack", "spacecraft file", "hardware file",
                                                     "gains file", "--params")


def _fields(node: str) -> dict:
    """``node``'s schema fields by name (a field shared by two schemas once)."""
    return {f.name: f for f in NODE_FIELDS[node]}


def flight_settings(environment: str, epoch_time_ns: int) -> dict:
    """What the full flight stack sets over the schemas' defaults (as ``magtune sil --modes --attitude estimator``).

    Parameters
    ----------
    environment : str
        The estimator's on-board models, "full" (IGRF at the position fix, Sun of date) or "paper".
    epoch_time_ns : int
        The spacecraft epoch [ns since 1970]: the stamp of sim time 0.

    Returns
    -------
    dict
        node -> {name: value}.
    """
    return {"controller": {"autostart": False},
            "mode_manager": {"managed_nodes": ["attitude_sensors", "attitude_estimator", "controller"]},
            "attitude_estimator": {"autostart": False, "validity_gate": True, "environment": environment,
                                   "time_origin_ns": int(epoch_time_ns)}}


@dataclass
class FlightTable:
    """The flight nodes' parameters and where each came from.

    ``raw`` node -> {name: value as written}; ``values`` node -> parsed values (numpy arrays for lists);
    ``sources`` node -> {name: source}; ``mission`` the spacecraft parameters as written (``/**``);
    ``spacecraft`` the parsed spacecraft; ``gains`` the gains (provenance included); ``files`` role ->
    path of each source file read; ``residual_dipole`` [A m^2] the simulated disturbance of the reference run.
    """

    raw: dict
    values: dict
    sources: dict
    mission: dict
    spacecraft: SpacecraftParams
    gains: Gains | None = None
    files: dict = field(default_factory=dict)
    residual_dipole: tuple = (0.0, 0.0, 0.0)

    @property
    def orbit_rate(self) -> float:
        """W0 [rad/s] of the law's state (eq. 14): the spacecraft's nominal orbit rate.

        Returns
        -------
        float
            The orbit rate [rad/s].
        """
        return float(self.spacecraft.orbit_rate)

    @property
    def bdot_gain(self) -> float:
        """The controller's B-dot gain as flown [N m s] (the rule's value when ``bdot_gain`` is 0).

        Returns
        -------
        float
            The gain.
        """
        return resolved_bdot_gain(self.values["controller"], self.spacecraft)


def _plain(v):
    """A YAML/JSON-plain value (floats as Python floats, lists as lists)."""
    if isinstance(v, np.ndarray):
        return [_plain(x) for x in v.tolist()]
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, dict):
        return {k: _plain(x) for k, x in v.items()}
    if isinstance(v, np.generic):
        return v.item()
    return v


def _written(f, v):
    """A parsed value as a ROS parameter file needs it (rcl: doubles as floats, lists of one type)."""
    if f.kind == "float":
        return float(v)
    if f.kind == "float[]":
        return [float(x) for x in np.asarray(v, dtype=float).ravel()]
    if f.kind == "int":
        return int(v)
    if f.kind == "bool":
        return bool(v)
    if f.kind == "str[]":
        return [str(x) for x in v]
    return str(v)


def _mission(doc: dict, p: SpacecraftParams) -> dict:
    """The spacecraft file's own parameters for the ``/**`` section: the derived ``orbit_period`` written out, a
    ``tle_file`` replaced by its lines (the parameter file lives elsewhere), as ``ros.scenario`` hands them to a node."""
    own = {f.name for f in MISSION_FIELDS}
    out = {k: _plain(v) for k, v in merge_ros_params(doc).items() if k in own}
    out["orbit_period"] = float(p.orbit_period)
    if out.pop("tle_file", ""):
        out["tle"] = ([p.tle.name] if p.tle.name else []) + [p.tle.line1, p.tle.line2]
    return out


def _layers(node: str, settings: dict, sc_doc: dict, gains_params: dict, params_doc: dict | None, hw=None) -> list:
    """(source, mapping) of ``node`` from the lowest to the highest (restricted to the node's schema)."""
    names = _fields(node)
    pick = lambda m: {k: v for k, v in m.items() if k in names}  # noqa: E731
    layers = [(STACK, settings.get(node, {})), (SPACECRAFT, pick(merge_ros_params(sc_doc, node)))]
    if hw is not None:
        layers.append((HARDWARE, pick(hw.node_parameters().get(node, {}))))
    if node == CONTROLLER_NODE:
        layers.append((GAINS, pick(gains_params)))
    if params_doc is not None:
        layers.append((PARAMS, pick(merge_ros_params(params_doc, node))))
    return layers


def _check_params_names(params_doc: dict, where) -> None:
    """Every key of the ``--params`` file is a flight node's or a spacecraft parameter (one line naming it otherwise)."""
    known = sorted({f.name for node in FLIGHT_NODES for f in NODE_FIELDS[node]} | {f.name for f in MISSION_FIELDS})
    for section in params_doc.values():
        params = (section or {}).get("ros__parameters", {}) if isinstance(section, dict) else {}
        parse(params, (), where, allowed=known + ["use_sim_time"])


def parse_nodes(raw: dict, where) -> dict:
    """Validate each flight node's parameters by its schema (and the mode schema's cross-field rules).

    Parameters
    ----------
    raw : dict
        node -> {name: value}.
    where : str or Path
        What the values came from, named in errors.

    Returns
    -------
    dict
        node -> parsed values (defaults filled in).

    Raises
    ------
    ConfigError
        A value out of its schema (one line naming ``where`` and the field).
    """
    out = {}
    for node in FLIGHT_NODES:
        v = parse(raw.get(node, {}), NODE_FIELDS[node], where)
        if node == "mode_manager":
            check_modes(v, where)
        out[node] = v
    return out


def build_table(gains_path, spacecraft_path, params_path=None, environment: str = "full", hardware_path=None) -> FlightTable:
    """The flight table of a gains file, a spacecraft file and an optional parameter file (module docstring).

    Parameters
    ----------
    gains_path : str or Path
        The gains file (``magtune tune`` output).
    spacecraft_path : str or Path
        The spacecraft file (its ``/**`` section: the mission data; its node sections: node parameters).
    params_path : str or Path, optional
        A ROS 2 parameter file with sections for the flight nodes (``/**``, ``/**/mode_manager``, ...), e.g. the
        mode thresholds or the estimator's noise figures; an exported ``flight_params.yaml`` is one.
    environment : str
        The estimator's on-board models unless the parameter file sets ``environment``.
    hardware_path : str or Path, optional
        A hardware file (:mod:`magtune_core.design.hardware`): a layer between the spacecraft file and the gains
        file (a spacecraft node section that gives one of its parameters another value is refused).

    Returns
    -------
    FlightTable
        Every value validated, with its source.

    Raises
    ------
    ConfigError
        A bad file or value (one line naming the file and field), or a ``ts`` other than the gains file's.
    """
    gains_params = check_ros_params(gains_path, CONTROLLER_NODE)
    gains = Gains.from_mapping(gains_params, gains_path)
    sc_doc = load_ros_params(spacecraft_path)
    p = SpacecraftParams.from_mapping(merge_ros_params(sc_doc), spacecraft_path, strict=True,
                                      base_dir=Path(spacecraft_path).parent)
    warn_tle(p, spacecraft_path)
    hw = load_hardware(hardware_path) if hardware_path is not None else None
    if hw is not None:
        check_spacecraft_agrees(hw, sc_doc, spacecraft_path)
    params_doc = None
    if params_path is not None:
        params_doc = load_ros_params(params_path)
        _check_params_names(params_doc, params_path)
    settings = flight_settings(environment, epoch_ns(p.epoch))
    raw, sources = {}, {}
    for node in FLIGHT_NODES:
        values, src = {}, {}
        for source, mapping in _layers(node, settings, sc_doc, gains_params, params_doc, hw):
            values.update(mapping)
            src.update({k: source for k in mapping})
        raw[node], sources[node] = values, src
    if "initial_mode" not in sources["controller"] or sources["controller"]["initial_mode"] == SPACECRAFT:
        # the controller starts in the mode manager's first mode (ros.scenario does the same with --modes)
        raw["controller"]["initial_mode"] = raw["mode_manager"].get("initial_mode", _fields("mode_manager")["initial_mode"].default)
        sources["controller"]["initial_mode"] = sources["mode_manager"].get("initial_mode", DEFAULT)
    for node in FLIGHT_NODES[1:]:
        ts = raw[node].get("ts")
        if ts is not None and sources[node].get("ts") == PARAMS and float(ts) != gains.ts:
            raise ConfigError(params_path, "ts", f"{node}: {ts:g} s differs from the gains file's {gains.ts:g} s: "
                                                  "every flight node runs at the design's sample period; remove it")
        raw[node]["ts"], sources[node]["ts"] = gains.ts, GAINS
    where = params_path if params_path is not None else spacecraft_path
    values = parse_nodes(raw, where)
    for node in FLIGHT_NODES:
        flds = _fields(node)
        raw[node] = {name: _written(flds[name], values[node][name]) for name in flds
                     if not (flds[name].kind == "str[]" and values[node][name] == () and name not in raw[node])}
        for name in flds:
            sources[node].setdefault(name, DEFAULT)
    residual = tuple(hw.node_parameters()["simulator"].get("residual_dipole", _residual_dipole(sc_doc)) if hw else _residual_dipole(sc_doc))
    files = {"gains": Path(gains_path), "spacecraft": Path(spacecraft_path)}
    if hw is not None:
        files["hardware"] = Path(hardware_path)
    if p.tle_field == "tle_file":
        files["tle_file"] = Path(spacecraft_path).parent / merge_ros_params(sc_doc)["tle_file"]
    if params_path is not None:
        files["params"] = Path(params_path)
    return FlightTable(raw, values, sources, _mission(sc_doc, p), p, gains, files, residual)


def _residual_dipole(sc_doc: dict) -> tuple:
    """The simulator's residual dipole [A m^2] of the spacecraft file (the schema's default without one)."""
    f = next(f for f in SIL_NODE_FIELDS["simulator"] if f.name == "residual_dipole")
    v = parse(merge_ros_params(sc_doc, "simulator"), (f,), "spacecraft file")
    return tuple(float(x) for x in v["residual_dipole"])


# ---------------------------------------------------------------- the ROS 2 parameter file
def parameter_file_text(table: FlightTable, header: str = "") -> str:
    """The ROS 2 parameter file of ``table``: ``/**`` the mission data, ``/**/<node>`` each flight node's values.

    Parameters
    ----------
    table : FlightTable
        The table.
    header : str
        Comment lines put first.

    Returns
    -------
    str
        YAML text (floats written by PyYAML's repr: they read back bit for bit).
    """
    doc = {"/**": {"ros__parameters": table.mission}}
    for node in FLIGHT_NODES:
        doc[f"/**/{node}"] = {"ros__parameters": table.raw[node]}
    lines = [f"# {h}" if h else "#" for h in header.splitlines()]
    return "\n".join(lines) + ("\n" if lines else "") + yaml.safe_dump(doc, sort_keys=False, width=120)


def read_parameter_file(path) -> FlightTable:
    """A flight table from a parameter file :func:`parameter_file_text` wrote, read as each node reads it
    (rcl's rules: :func:`~magtune_core.base.paramfile.check_ros_params` for each node, then its schema).

    Parameters
    ----------
    path : str or Path
        The parameter file.

    Returns
    -------
    FlightTable
        Values parsed by the schemas (every source ``--params``); no gains provenance.

    Raises
    ------
    ConfigError
        A node would refuse the file (one line naming the field).
    """
    raw, values = {}, {}
    p = None
    for node in FLIGHT_NODES:
        params = check_ros_params(path, node)
        p = SpacecraftParams.from_mapping(params, path)
        raw[node] = {k: v for k, v in params.items() if k in _fields(node)}
        if node == CONTROLLER_NODE:
            Gains.from_mapping(params, path)  # the controller's own check of its gains
    values = parse_nodes(raw, path)
    sources = {node: dict.fromkeys(_fields(node), PARAMS) for node in FLIGHT_NODES}
    mission = {k: v for k, v in check_ros_params(path).items() if k in {f.name for f in MISSION_FIELDS}}
    return FlightTable(raw, values, sources, mission, p, files={"params": Path(path)})


# ---------------------------------------------------------------- the C header
def c_double(x: float) -> str:
    """``x`` as a C double literal with 17 significant digits (``%.17g``: reads back bit for bit).

    Parameters
    ----------
    x : float
        A finite number.

    Returns
    -------
    str
        The literal, with a decimal point or an exponent (``50.0``, not ``50``).

    Raises
    ------
    ValueError
        If ``x`` is not finite (C99 has no literal for it).
    """
    x = float(x)
    if not math.isfinite(x):
        raise ValueError(f"{x!r} has no C99 literal")
    s = f"{x:.17g}"
    return s if any(c in s for c in ".en") else s + ".0"


def _comment(text: str) -> str:
    """A C comment's text: ASCII, no comment delimiters."""
    text = text.encode("ascii", "replace").decode().replace("*/", "* /").replace("/*", "/ *")
    return " ".join(text.split())


def _c_line(name: str, f, v) -> list[str]:
    """The C declaration(s) of one schema field's value."""
    unit = f" [{f.unit}]" if f.unit and f"[{f.unit}]" not in f.description else ""
    doc = f"/* {_comment(f.description + unit)} */"
    if f.kind == "float":
        return [doc, f"static const double {name} = {c_double(v)};"]
    if f.kind == "float[]":
        vals = ", ".join(c_double(x) for x in np.asarray(v, dtype=float).ravel())
        return [doc, f"static const double {name}[{len(np.asarray(v).ravel())}] = {{{vals}}};"]
    if f.kind == "int":
        return [doc, f"static const long long {name} = {int(v)}LL;"]
    if f.kind == "bool":
        return [doc, f"static const int {name} = {int(bool(v))};"]
    if f.kind == "str":
        text = str(v).encode("ascii", "replace").decode().replace("\\", "\\\\").replace('"', '\\"')
        lines = [doc, f'static const char {name}[] = "{text}";']
        if str(v) in MODES:
            lines.append(f"static const int {name}_ID = {MODES.index(str(v))};")
        return lines
    return []  # str[]: the ROS bring-up's node names, not flight data


def header_text(table: FlightTable, guard: str = "MAGTUNE_FLIGHT_TABLE_H", banner: str = "") -> str:
    """The C99 header of ``table``: ``static const`` data only, units in comments, a header guard.

    Parameters
    ----------
    table : FlightTable
        The table.
    guard : str
        The include guard's macro.
    banner : str
        Comment lines put first (provenance).

    Returns
    -------
    str
        The header (compiles with ``cc -std=c99 -Wall -Wextra -Werror -pedantic``).
    """
    out = ["/*"] + [f" * {_comment(b)}" if b else " *" for b in banner.splitlines()] + [" */",
                                                                                        f"#ifndef {guard}", f"#define {guard}", ""]
    out += ["/* flight modes: the mode ids of magtune_interfaces/msg/Mode */"]
    out += [f"static const int MAGTUNE_MODE_ID_{m} = {i};" for i, m in enumerate(MODES)]
    K = np.asarray(table.values["controller"]["gain"], dtype=float).reshape(3, 6)
    rows = ",\n    ".join("{" + ", ".join(c_double(x) for x in row) + "}" for row in K)
    out += ["", "/* controller: the gain K of u = K x (eq. 19), x = [dq; w + (0, 0, W0)] (eq. 14); rows: torque axes x, y, z "
            "[N m per rad, N m per rad/s]; m = sat(S(b)^T K x / |b|^2) (eq. 17) */",
            f"static const double MAGTUNE_CTRL_K[3][6] = {{\n    {rows}}};",
            "/* controller: orbit rate W0 of the law's state [rad/s] */",
            f"static const double MAGTUNE_CTRL_ORBIT_RATE = {c_double(table.orbit_rate)};",
            "/* controller: the B-dot gain flown [N m s] (bdot_gain, or its rule when bdot_gain is 0) */",
            f"static const double MAGTUNE_CTRL_BDOT_GAIN_FLOWN = {c_double(table.bdot_gain)};"]
    for node in FLIGHT_NODES:
        out += ["", f"/* ---- {node} */"]
        for name, f in _fields(node).items():
            if name != "gain":
                out += _c_line(C_PREFIX[node] + name.upper(), f, table.values[node][name])
    sc = table.spacecraft
    out += ["", "/* ---- spacecraft */"]
    out += _c_line("MAGTUNE_SC_INERTIA", MISSION_FIELDS[0], sc.inertia)
    out += ["/* wheel momentum in body axes [N m s]: h = (0, 0, -wheel_inertia * wheel_speed), the paper's sign (SPEC.md): "
            "a positive wheel_speed gives a negative h_z */",
            f"static const double MAGTUNE_SC_WHEEL_MOMENTUM[3] = {{{', '.join(c_double(x) for x in sc.wheel_momentum)}}};",
            "/* nominal orbit period [s] */", f"static const double MAGTUNE_SC_ORBIT_PERIOD = {c_double(sc.orbit_period)};",
            "/* epoch of sim time 0 (UTC), Julian date [d] */",
            f"static const double MAGTUNE_SC_EPOCH_JD = {c_double(sc.orbit_config().jd0)};", "", f"#endif /* {guard} */", ""]
    return "\n".join(out)


# ---------------------------------------------------------------- the JSON document
HASH_KEY = "sha256"


def canonical_bytes(doc: dict) -> bytes:
    """The canonical form of ``doc`` without its hash: ``json.dumps(sort_keys=True, separators=(",", ":"),
    ensure_ascii=True, allow_nan=False)`` of every key but ``sha256``, as ASCII bytes (docs/export.md).

    Parameters
    ----------
    doc : dict
        The document.

    Returns
    -------
    bytes
        What :func:`content_hash` hashes.
    """
    rest = {k: v for k, v in doc.items() if k != HASH_KEY}
    return json.dumps(rest, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False).encode("ascii")


def content_hash(doc: dict) -> str:
    """SHA-256 (hex) of :func:`canonical_bytes`.

    Parameters
    ----------
    doc : dict
        The document.

    Returns
    -------
    str
        64 hex digits.
    """
    return hashlib.sha256(canonical_bytes(doc)).hexdigest()


def file_sha256(path) -> str:
    """SHA-256 (hex) of a file's bytes.

    Parameters
    ----------
    path : str or Path
        The file (a regular file; read whole).

    Returns
    -------
    str
        64 hex digits.
    """
    return hashlib.sha256(read_regular(path, limit=None)).hexdigest()


def _finite(v):
    """JSON-safe: non-finite floats become None (the canonical form allows no NaN)."""
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, dict):
        return {str(k): _finite(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_finite(x) for x in v]
    return v


def document(table: FlightTable, shown, vectors: dict, files: dict, version: str) -> dict:
    """The JSON document of ``table`` (docs/export.md), its ``sha256`` the hash of its canonical content.

    Parameters
    ----------
    table : FlightTable
        The table (built from files: their hashes are recorded).
    shown : callable
        Path -> the text recorded for it (repository-relative where possible).
    vectors : dict
        The reference run's description (seed, steps, coverage, tolerance).
    files : dict
        Name -> SHA-256 of the other files written beside it.
    version : str
        The tool's version (``magtune_core.__version__``).

    Returns
    -------
    dict
        The document.
    """
    nodes = {}
    for node in FLIGHT_NODES:
        nodes[node] = {name: {"value": _plain(table.raw[node][name]) if name in table.raw[node] else [],
                              "unit": f.unit, "description": f.description, "source": table.sources[node][name]}
                       for name, f in _fields(node).items()}
    prov = dict(table.gains.provenance) if table.gains else {}
    design = {"sigma": table.gains.sigma if table.gains else None, **{k: prov.get(k) for k in (
        "J", "c1", "c2", "rho", "method", "seed", "design_field", "requirements", "requirements_source",
        "requirements_met", "hold_gain_margin", "hold_gain_margin_required", "hold_margin_min", "hold_tightest_ts",
        "hold_rho_max", "hold_certificate", "dipole_budget", "written")},
              "verification": prov.get("verification")}
    doc = {"format": FORMAT, "schema_version": SCHEMA_VERSION, "tool": {"name": "magtune", "version": version},
           "sources": {role: {"path": shown(path), "sha256": file_sha256(path)} for role, path in table.files.items()},
           "design": design,
           "defaults": sorted(f"{node}.{name}" for node in FLIGHT_NODES for name, s in table.sources[node].items()
                              if s == DEFAULT),
           "spacecraft": _plain(table.mission),
           "derived": {"orbit_rate": {"value": table.orbit_rate, "unit": "rad/s", "description": "W0 of the law's state"},
                       "bdot_gain_flown": {"value": table.bdot_gain, "unit": "N m s",
                                           "description": "bdot_gain, or its rule when bdot_gain is 0"},
                       "epoch_jd": {"value": table.spacecraft.orbit_config().jd0, "unit": "d",
                                    "description": "epoch of sim time 0 (UTC), Julian date"}},
           "nodes": nodes, "vectors": vectors, "files": dict(sorted(files.items()))}
    doc = _finite(doc)
    doc[HASH_KEY] = content_hash(doc)
    return doc
