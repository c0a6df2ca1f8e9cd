"""``daq rig list|show|init``: the built-in rigs, their parameters, channels and eigenfrequencies; a user's
own copy of one to edit (every command that takes ``--rig`` takes its path too).

Heavy modules are imported inside the command functions (marked ``# heavy``): `daq --help`
imports every cli module and must stay fast.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from daq.io.jsonout import print_json

USER_RIG_HEADER = """\
# Your own rig, copied from the built-in '{rig}' by `daq rig init`. Edit what your rig has: masses,
# stiffnesses, damping, normal load, drive speed, sensor rates and noise; keep `rig = "{rig}"` (it names
# the equations). Every command that takes --rig (and a model file's rig) accepts this file's path:
#   daq rig show {out}      daq sim {out} ...      daq model init {out} -o model.toml
# A value out of range is one error naming this file and the field.

"""


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
    from daq.physics.catalog import CATALOG
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


def cmd_rig_init(args: argparse.Namespace) -> int:
    # heavy: config validation (pydantic)
    from daq.config import load_rig, parse_rig, parse_toml, rig_path
    from daq.errors import InputError
    from daq.io.files import atomic_path

    cfg = load_rig(args.rig)
    out = Path(args.output)
    if out.suffix.lower() != ".toml":
        raise InputError(str(out), "-o", "a rig file must end in .toml")
    if out.exists() and not args.force:
        raise InputError(str(out), "-o", "exists (give --force to overwrite)")
    text = rig_path(args.rig).read_text(encoding="utf-8")
    if not text.startswith("# Your own rig"):
        text = USER_RIG_HEADER.format(rig=cfg.rig, out=out.name) + text
    parse_rig(parse_toml(text, str(out)), str(out))  # what we write must load
    with atomic_path(out) as tmp:
        Path(tmp).write_text(text, encoding="utf-8")
    print(f"wrote {out}: an editable copy of {cfg.rig} ({cfg.title})", file=sys.stderr)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    rig = sub.add_parser("rig", help="rig configurations")
    rsub = rig.add_subparsers(dest="rig_command", required=True)
    rsub.add_parser("list", help="list rigs").set_defaults(func=cmd_rig_list)
    show = rsub.add_parser("show", help="parameters, channels, eigenfrequencies")
    show.add_argument("rig", help="a built-in rig or a rig TOML file")
    show.add_argument("--json", action="store_true")
    show.set_defaults(func=cmd_rig_show)
    init = rsub.add_parser("init", help="write an editable copy of a rig for your own set-up")
    init.add_argument("rig", help="the built-in rig (or a rig file) to start from")
    init.add_argument("-o", "--output", required=True, help="MY-RIG.toml")
    init.add_argument("--force", action="store_true", help="overwrite an existing file")
    init.set_defaults(func=cmd_rig_init)
