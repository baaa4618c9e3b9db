"""``magtune analyze``: J, c1, c2, rho of a gains file (paper eqs. 21, 28-30), recomputed."""
from __future__ import annotations

import json

from ..design.gains import load_gains
from ..design.problem import figures
from .common import ANALYSIS_STEPS, field_model_argument, load_model


def register(sub) -> None:
    a = sub.add_parser("analyze", help="J, c1, c2, rho of a gains file")
    a.add_argument("path", help="gains parameter file (config/gains/sigma_*.yaml)")
    a.add_argument("--json", action="store_true", help="one JSON object with keys J, c1, c2, rho, stable")
    a.add_argument("--steps", type=int, default=ANALYSIS_STEPS, help="Magnus intervals per period")
    field_model_argument(a)
    a.set_defaults(func=run)


def run(args) -> int:
    model = load_model(args)
    g = load_gains(args.path)
    fig = figures(model, g.K, g.sigma, steps=args.steps)
    d = fig.as_dict()
    if args.json:
        print(json.dumps({k: d[k] for k in ("J", "c1", "c2", "rho", "stable")}))
        return 0
    print(f"{args.path}: sigma={g.sigma:g}, field model {model.field.name}, {args.steps} Magnus steps")
    for key, label in (("J", "H-inf T_d -> z"), ("c1", "H-inf T_d -> dq"), ("c2", "H2 T_d -> m"), ("rho", "max |multiplier|")):
        rec = g.provenance.get(key)
        extra = f"   (file: {rec:.6g}, diff {abs(d[key] - rec) / abs(rec):.1e})" if isinstance(rec, (int, float)) and rec else ""
        print(f"  {key:4s} {label:18s} {d[key]:.6g}{extra}")
    print(f"  closed loop {'stable' if fig.stable else 'UNSTABLE'}")
    return 0
