"""``magtune analyze``: J, c1, c2, rho of a gains file (paper eqs. 21, 28-30), recomputed; with
``--spec``, also the design spec's hard requirements (exit 3 when one is not met, as ``verify``)."""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

from ..base import jsonout
from ..base.errors import ConfigError
from ..design.gains import load_gains
from ..design.pipeline import ANALYSIS_STEPS, analyze_gains, gain_sensitivity, requirement_lines, requirement_provenance
from ..design.requirements import claim_contradictions
from ..design.resolution import resolved_steps
from .common import CommandError, add_spec_argument, field_model_argument, load_design_spec, load_model


def register(sub) -> None:
    a = sub.add_parser("analyze", help="J, c1, c2, rho of a gains file")
    a.add_argument("path", help="gains parameter file (config/gains/sigma_*.yaml)")
    a.add_argument("--json", action="store_true",
                   help="one JSON object with keys J, c1, c2, rho, stable, ts, hold_gain_margin")
    a.add_argument("--steps", type=int, default=None,
                   help=f"Magnus intervals per period (default: {ANALYSIS_STEPS}, doubled until J agrees with "
                        "twice as many to 1e-3; see magtune_core/design/resolution.py)")
    a.add_argument("--robust", metavar="SPEC", default=None,
                   help="robust spec YAML (docs/robust.md): also J, c1, c2, rho on every model of the set, "
                        "the worst case and the worst model")
    a.add_argument("--sensitivity", action="store_true",
                   help="also the exact gradient of J: K_ij dJ/dK_ij / J per gain entry (the %% change of J per %% "
                        "change of the entry) and the worst-case disturbance frequency (magtune_core/ltp/hinf_gradient.py)")
    a.add_argument("--requirements", action="store_true",
                   help="also check the hard requirements of the design spec (--spec; default config/design.yaml): "
                        "hold margin over the sample-period range (dense scan), peak-dipole budget; exit 3 if one "
                        "is not met")
    a.add_argument("--record", action="store_true",
                   help="with --requirements: write the recomputed requirement figures and hold certificate into "
                        "the gains file's provenance (atomic; its requirements_met then says what was proven)")
    a.add_argument("--margin-plot", metavar="PNG", default=None,
                   help="with --requirements: plot the held loop's first unstable gain scale at every admissible "
                        "sample period, on a grid up to twice the required margin (step 0.01; an existing file is "
                        "kept unless --force)")
    a.add_argument("--force", action="store_true", help="overwrite an existing --margin-plot")
    add_spec_argument(a)
    field_model_argument(a)
    a.set_defaults(func=run)


def run(args) -> int:
    if args.robust and args.sensitivity:
        raise ConfigError("--sensitivity", None, "is for the nominal model: leave out --robust (or --sensitivity)")
    if args.robust and args.requirements:  # the robust figures do not evaluate the design spec's requirements
        raise ConfigError("--requirements", None, "is checked on the nominal model: leave out --robust (its figures "
                          "check no requirement), or verify under dispersions with magtune verify")
    for opt, given in (("--spec", args.spec), ("--hardware", args.hardware)):  # a file given is a file read
        if given and not args.requirements:
            raise ConfigError(opt, None, "is read with --requirements only; add --requirements")
    if args.record and not args.requirements:
        raise ConfigError("--record", None, "records the requirement figures: add --requirements")
    if args.margin_plot and not args.requirements:
        raise ConfigError("--margin-plot", None, "plots the hold requirement: add --requirements")
    if args.margin_plot and Path(args.margin_plot).exists() and not args.force:
        raise ConfigError(args.margin_plot, None, "exists; choose another --margin-plot or add --force")
    model = load_model(args)
    g = load_gains(args.path)
    req = load_design_spec(args) if args.requirements else None
    if args.robust:
        return run_robust(args, model, g)
    a = analyze_gains(model, g, steps=args.steps)
    args.steps, fig, margin, sens = a.steps, a.figures, a.hold_gain_margin, None
    if args.sensitivity and fig.stable:
        try:
            sens = gain_sensitivity(model, g, a.steps)
        except (ArithmeticError, ValueError, np.linalg.LinAlgError) as exc:  # e.g. flow not finite at the norm
            raise CommandError(f"--sensitivity: the gradient of J could not be computed ({exc})") from None
    d = fig.as_dict()
    rp = requirement_provenance(model, g.K, req) if req is not None else None
    contradicted = claim_contradictions(g.provenance)  # the file's claim against its own figures
    if args.margin_plot:
        _margin_plot(args, model, g, req)
    if rp is not None and args.record:  # the file now says what the recomputation proved
        _record(args.path, rp)
        contradicted = []
    status = 0 if (rp is None or rp["requirements_met"]) and not (req is not None and contradicted) else 3
    if args.json:
        reqs = {"requirements": {**rp, "claim_contradictions": contradicted}} if rp else {}
        print(jsonout.dumps({**{k: d[k] for k in ("J", "c1", "c2", "rho", "stable")}, "ts": g.ts,
                          "hold_gain_margin": margin, **(sens or {}), **reqs}))
        return status
    print(f"{args.path}: sigma={g.sigma:g}, field model {model.field.name}, {args.steps} Magnus steps")
    for key, label in (("J", "H-inf T_d -> z"), ("c1", "H-inf T_d -> dq"), ("c2", "H2 T_d -> m"), ("rho", "max |multiplier|")):
        rec = g.provenance.get(key)
        extra = f"   (file: {rec:.6g}, diff {abs(d[key] - rec) / abs(rec):.1e})" if isinstance(rec, (int, float)) and rec else ""
        print(f"  {key:4s} {label:18s} {d[key]:.6g}{extra}")
    print(f"  closed loop {'stable' if fig.stable else 'UNSTABLE'}")
    held = (f"UNSTABLE when held at Ts = {g.ts:g} s (sample-and-hold, design/sampled.py)" if margin == 0 else
            f"sample-and-hold at Ts = {g.ts:g} s: gain margin {margin:.3g}"
            + (" or more" if margin >= 16 else f" ({20 * math.log10(margin):.1f} dB)"))
    print(f"  {held}")
    if rp:
        print(f"  requirements ({rp['requirements']}): {'met' if rp['requirements_met'] else 'NOT MET'}")
        for line in requirement_lines(rp, req.gain_margin):
            print(f"    {line}")
    for line in contradicted:
        print(f"  the file claims requirements_met, contradicted by {line}")
    if sens:
        print(f"  worst-case disturbance: multiplier angle {sens['worst_multiplier_angle']:.4f} rad, i.e. frequency "
              f"{sens['worst_frequency_mod_orbit']:.4g} rad/s modulo the orbital rate {sens['orbit_rate']:.4g} rad/s")
        print("  elasticity K_ij dJ/dK_ij / J (gradient of the active peak; at a tuned optimum J has a kink):")
        print("           " + " ".join(f"{c:>8s}" for c in ("dq_x", "dq_y", "dq_z", "dw_x", "dw_y", "dw_z")))
        for i, row in enumerate(sens["elasticity"]):
            print(f"    u_{'xyz'[i]}    " + " ".join(f"{v:8.3f}" for v in row))
    return status


def _margin_plot(args, model, g, req) -> None:
    """The first unstable scale per admissible period up to twice the margin (studies.hold_margin)."""
    from ..design.hold_certificate import certify_hold
    from ..studies.hold_margin import margin_figure

    if not req.gain_margin:
        raise CommandError("--margin-plot: the design spec has no hold requirement (gain_margin 0)")
    s = req.sampling
    cert = certify_hold(model, g.K, s["ts_min"], s["ts_max"], 2.0 * req.gain_margin, step=0.01, guard=0.0)
    margin_figure(cert, args.margin_plot, req.gain_margin, float(s["guard"]),
                  f"{Path(args.path).name}: held-loop margin against the sample period ({len(cert.periods)} periods, "
                  "k step 0.01)")
    print(f"wrote {args.margin_plot} ({cert.seconds:.0f} s)", file=sys.stderr)


def _record(path, rp: dict) -> None:
    """The recomputed requirement figures into the gains file (the margin at ts_min alone, ``hold_gain_margin``,
    goes: the certificate covers the range), under the file's lock."""
    from ..base.atomic import output_lock
    from ..design.gains import update_provenance

    with output_lock(path, "magtune analyze --record", directory=False, option="PATH"):
        update_provenance(path, rp, drop=("hold_gain_margin",))
    print(f"recorded the requirement figures in {path}", file=sys.stderr)


def run_robust(args, model, g) -> int:
    """``analyze --robust SPEC``: figures on every model of the spec's set, nominal and worst case."""
    from ..design.robust import load_robust_spec, model_set, robust_figures

    skipped: list = []
    models = model_set(model, load_robust_spec(args.robust), args.robust, skipped=skipped)
    args.steps = args.steps or resolved_steps([m.model for m in models], g.K, g.sigma, ANALYSIS_STEPS)[0]
    rf = robust_figures(models, g.K, g.sigma, steps=args.steps)
    nom, worst = rf.nominal(), rf.worst()
    if args.json:
        print(jsonout.dumps({"nominal": nom.as_dict() if nom else None, "worst": worst, "worst_model": rf.worst_name,
                          "stable_all": all(f.stable for f in rf.figures),
                          "models": {n: f.as_dict() for n, f in zip(rf.names, rf.figures)}}))
        return 0
    print(f"{args.path}: sigma={g.sigma:g}, nominal field {model.field.name}, {len(models)} models "
          f"({args.robust}), {args.steps} Magnus steps")
    print(f"  {'model':48s} {'J':>10s} {'c1':>10s} {'c2':>10s} {'rho':>9s}")
    for n, f in zip(rf.names, rf.figures):
        print(f"  {n[:48]:48s} {f.J:10.5g} {f.c1:10.5g} {f.c2:10.5g} {f.rho:9.6f}" + ("" if f.stable else "  UNSTABLE"))
    if nom:
        print(f"  {'NOMINAL':48s} {nom.J:10.5g} {nom.c1:10.5g} {nom.c2:10.5g} {nom.rho:9.6f}")
    print(f"  {'WORST CASE':48s} {worst['J']:10.5g} {worst['c1']:10.5g} {worst['c2']:10.5g} {worst['rho']:9.6f}")
    if skipped:
        print(f"  left out (not a rigid body): {'; '.join(skipped)}")
    print(f"  worst model (largest J): {rf.worst_name}"
          + ("" if all(f.stable for f in rf.figures) else "; some closed loops are UNSTABLE"))
    return 0
