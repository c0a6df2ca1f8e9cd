"""``daq rig list|show``: the built-in rigs, their parameters, channels and eigenfrequencies.

Heavy modules are imported inside the command functions (marked ``# heavy``): `daq --help`
imports every cli module and must stay fast.
"""

from __future__ import annotations

import argparse

from daq.io.jsonout import print_json


def cmd_rig_list(args: argparse.Namespace) -> int:
    # heavy: config validation (pydantic) only when the command runs
    from daq.config import load_rig, rig_ids

    for rid in rig_ids():
        cfg = load_rig(rid)
        print(f"{rid:15s} paper {cfg.paper}  {cfg.title}")
    return 0


def rig_summary(rig: str) -> dict:
    """Parameters, channels, effects and linearised eigenfrequencies of a rig (its seed configuration)."""
    # heavy: the compiled physics
    from daq.config import load_rig
    from daq.physics.effects import CATALOG
    from daq.sim.effectset import effect_vector
    from daq.sim.rigs import make_sim

    cfg = load_rig(rig)
    e, active = effect_vector(cfg)
    sim = make_sim(cfg, e)
    return {
        "rig": cfg.rig,
        "title": cfg.title,
        "paper": cfg.paper,
        "mechanics": cfg.mechanics.model_dump(),
        "friction": cfg.friction.model_dump(),
        "drive": cfg.drive.model_dump(exclude_none=True),
        "channels": {k: {"unit": c.unit, "instrument": c.instrument, "description": c.description}
                     for k, c in cfg.channels.items()},
        "seed_effects": active,
        "applicable_effects": [n for n, s in CATALOG.items() if cfg.rig in s.rigs],
        "effect_defaults": cfg.effects,
        "linear_modes_hz": sim.modes_hz(),
        "chosen": cfg.chosen,
    }


def cmd_rig_show(args: argparse.Namespace) -> int:
    info = rig_summary(args.rig)
    if args.json:
        print_json(info)
        return 0
    print(f"{info['rig']}: {info['title']} (paper {info['paper']})")
    for section in ("mechanics", "friction", "drive"):
        print(f"  [{section}]")
        for k, v in info[section].items():
            print(f"    {k:22s} {v}")
    print("  channels:")
    for k, c in info["channels"].items():
        print(f"    {k:12s} [{c['unit']}]  {c['instrument']}: {c['description']}")
    print("  seed effects: " + ", ".join(f"{k} {v}" for k, v in info["seed_effects"].items()))
    print("  applicable effects: " + ", ".join(info["applicable_effects"]))
    print("  linearised eigenfrequencies [Hz]:")
    for k, v in info["linear_modes_hz"].items():
        print(f"    {k:22s} " + ", ".join(f"{f:.3f}" for f in v))
    if info["rig"] == "brake-2dof":
        print("    (paper 001 prints 9.87/14.20 Hz; its printed equations give these values, see README)")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    rig = sub.add_parser("rig", help="rig configurations")
    rsub = rig.add_subparsers(dest="rig_command", required=True)
    rsub.add_parser("list", help="list rigs").set_defaults(func=cmd_rig_list)
    show = rsub.add_parser("show", help="parameters, channels, eigenfrequencies")
    show.add_argument("rig")
    show.add_argument("--json", action="store_true")
    show.set_defaults(func=cmd_rig_show)
