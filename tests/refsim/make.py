"""Write a recording of a reference rig: interchange CSV + JSON sidecar with the truth.

    python tests/refsim/make.py brake-2dof --effect stick-log:b=0.05,theta=0.1 \\
        --effect waviness:w=0.03,wavelength=0.05 --rate 100 --V0 0.2 --Tmax 60 \\
        --duration 20 --seed 3 -o out.csv

    python tests/refsim/make.py belt-ndof --steps 0.2:5,0.06:5,0.2:5 --effect stick-log:b=0.05 \\
        [--rig-file rig-2-masses.toml] --duration 15 -o belt.csv

writes ``out.csv`` (header ``t,x1,phi,vb,vb_set,temp``; belt-ndof ``t,x1[,x2,x3],vb,vb_set,temp``; SI units,
as ``daq``'s CSV reader expects; with ``--truth`` also ``truth_*`` columns, which that reader keeps
apart from the channels) and ``out.json`` (effects with their magnitudes and the
phenomenon each is an instance of, seed, drive, sensors, integrator, timings).
Bad input: one line on stderr, exit status 2, no output files.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

if __package__ in (None, ""):  # run as a script: make the package importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from refsim import belt, brake, drum, sensors
    from refsim import effects as fx
else:
    from . import belt, brake, drum, sensors
    from . import effects as fx

VERSION = "refsim 1"
RIGS = {"brake-2dof": brake.BrakeRig, "drum-pendulum": drum.DrumRig, "belt-ndof": belt.BeltRig}


def generate(rig: str = "brake-2dof", effects=(), *, rate: float | None = None, V0: float | None = None,
             Tmax: float | None = None, duration: float | None = None, lead_in: bool = False,
             steps: str | list[tuple[float, float]] | None = None, table: tuple | None = None, seed: int = 0,
             noise: bool = True, jitter_s: float = 0.0, spike_prob: float = 0.0, spike_sigma: float = 30.0,
             burst_prob: float = 0.0,
             rtol: float = 1e-7, method: str = "RK45", cfg: dict | None = None) -> dict:
    """Simulate a reference rig and its instruments. Returns t, channels, truth, meta.

    ``steps`` (belt-ndof only): a velocity-stepping programme, ``"V1:T1,V2:T2,..."`` or [(V1, T1), ...] [m/s, s],
    ramps at the config's max_accel_m_per_s2. ``cfg`` may be a user's rig file loaded by effects.load_config
    (belt-ndof with n_masses = 2 or 3). ``table`` (any rig): a programme as (t, speed) points, e.g. a ramp file's table
    (effects.TableDrive); the record lasts as long as it unless ``duration`` says otherwise."""
    if rig not in RIGS:
        raise fx.SpecError(f"rig {rig!r}: unknown (known: {', '.join(RIGS)})")
    cfg = cfg if cfg is not None else fx.load_config(rig)
    eff = effects if isinstance(effects, fx.EffectSet) else fx.EffectSet.parse(effects, rig)
    if V0 is not None and not 0.0 < V0 <= cfg["drive"]["max_speed_m_per_s"]:
        raise fx.SpecError(f"--V0 {V0}: must be in (0, {cfg['drive']['max_speed_m_per_s']}] m/s")
    if Tmax is not None and not Tmax > 0:
        raise fx.SpecError(f"--Tmax {Tmax}: must be > 0")
    if table is not None:
        drive = fx.TableDrive(list(table[0]), list(table[1]))
        if drive.describe()["v_max_m_per_s"] > cfg["drive"]["max_speed_m_per_s"]:
            raise fx.SpecError(f"table: speed above the rig's {cfg['drive']['max_speed_m_per_s']} m/s")
        duration = duration if duration is not None else float(table[0][-1])
    elif steps is not None:
        if rig != "belt-ndof":
            raise fx.SpecError(f"--steps: only for belt-ndof (not {rig})")
        a_max = float(cfg["drive"]["max_accel_m_per_s2"])
        drive = fx.StepDrive.parse(steps, a_max) if isinstance(steps, str) else fx.StepDrive(list(steps), a_max)
        for v, _ in drive.segments:
            if not 0.0 < v <= cfg["drive"]["max_speed_m_per_s"]:
                raise fx.SpecError(f"--steps: speed {v} must be in (0, {cfg['drive']['max_speed_m_per_s']}] m/s")
    else:
        drive = fx.default_drive(cfg, V0, Tmax, lead_in)
    duration = float(duration if duration is not None else
                     min(cfg["drive"]["default_duration_s"], getattr(drive, "Tmax", None) or math.inf))
    if not duration > 0:
        raise fx.SpecError(f"--duration {duration}: must be > 0")
    rate = float(rate or cfg["sensors"]["rate_Hz"])
    if not rate > 0:
        raise fx.SpecError(f"--rate {rate}: must be > 0")
    opt = sensors.SensorOptions(rate=rate, noise=noise, jitter_s=jitter_s, spike_prob=spike_prob,
                                spike_sigma=spike_sigma, burst_prob=burst_prob)
    rng = np.random.default_rng(seed)
    t_nom, t_true = sensors.sample_instants(duration, opt, rng)
    model = RIGS[rig](cfg, eff, drive)
    tr = model.simulate(t_true, rtol=rtol, method=method, max_step=min(1e-3, 1.0 / rate))
    true_ch = model.true_channels(tr)
    channels = sensors.measure_all(cfg, t_nom, true_ch, opt, rng)
    truth = {**{f"true_{k}": v for k, v in true_ch.items()}, **model.truth(tr)}
    meta = {
        "generator": VERSION,
        "rig": rig,
        "rig_config": cfg.get("_path"),
        "effects": eff.truth(),
        "expected": eff.expected(),
        "seed": seed,
        "rate_Hz": rate,
        "duration_s": duration,
        "drive": drive.describe(),
        "sensors": {"noise": noise, "jitter_s": jitter_s, "spike_prob": spike_prob, "spike_sigma": spike_sigma,
                    "burst_prob": burst_prob},
        "integrator": {"scipy": "solve_ivp", "method": method, "rtol": rtol, "max_step_s": min(1e-3, 1.0 / rate),
                       "nfev": tr.nfev, "wall_s": round(tr.wall_s, 3)},
        "units": {n: cfg["channels"][n].get("unit", "") for n in channels},
        "springs_N_per_m": ({"k1": model.k1, "k2": model.k2, "k3": model.k3} if rig == "brake-2dof" else
                            {"k": model.p.K, "n_masses": model.n} if rig == "belt-ndof" else {"k": model.k}),
        "modes_hz": [round(float(f), 4) for f in model.linear_modes()],
    }
    return {"t": t_nom, "channels": channels, "truth": truth, "meta": meta}


def write(rec: dict, path: str | Path, truth: bool = False) -> tuple[Path, Path]:
    """CSV + JSON sidecar, each written to a temporary file and renamed (no partial output)."""
    path = Path(path)
    side = path.with_suffix(".json")
    cols = {"t": rec["t"], **rec["channels"]}
    if truth:
        cols.update({f"truth_{k}": v for k, v in rec["truth"].items()})
    data = np.column_stack([np.asarray(v, dtype=float) for v in cols.values()])
    tmp_csv = tmp_json = None
    try:
        fd, tmp_csv = tempfile.mkstemp(dir=path.parent or ".", prefix=".refsim-", suffix=".csv")
        with os.fdopen(fd, "w", newline="") as fh:
            fh.write(",".join(cols) + "\n")
            np.savetxt(fh, data, delimiter=",", fmt="%.10g")
        fd, tmp_json = tempfile.mkstemp(dir=path.parent or ".", prefix=".refsim-", suffix=".json")
        with os.fdopen(fd, "w") as fh:
            json.dump({**rec["meta"], "csv": path.name}, fh, indent=1)
        os.replace(tmp_csv, path)
        tmp_csv = None
        os.replace(tmp_json, side)
        tmp_json = None
    finally:
        for f in (tmp_csv, tmp_json):
            if f and os.path.exists(f):
                os.unlink(f)
    return path, side


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="refsim", description="reference rig simulator (tests only; shares no code with daq)")
    ap.add_argument("rig", choices=sorted(RIGS))
    ap.add_argument("--effect", action="append", default=[], metavar="NAME[:key=val,...]",
                    help=f"hidden effect; names: {', '.join(fx.EFFECTS)}")
    ap.add_argument("--rate", type=float, default=None, help="sampling rate [Hz] (config's by default)")
    ap.add_argument("--V0", type=float, default=None, help="initial belt (drum surface) speed [m/s]")
    ap.add_argument("--Tmax", type=float, default=None, help="ramp duration of eq. (11) [s]")
    ap.add_argument("--duration", type=float, default=None, help="record length [s]")
    ap.add_argument("--lead-in", action="store_true", help="start the drive from rest at its max acceleration")
    ap.add_argument("--steps", default=None, metavar="V1:T1,V2:T2,...",
                    help="belt-ndof: belt speed steps [m/s : s], ramps at the config's max acceleration")
    ap.add_argument("--rig-file", default=None, help="a user's rig file (e.g. belt-ndof with n_masses = 2)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-noise", action="store_true")
    ap.add_argument("--jitter", type=float, default=0.0, metavar="S", help="clock jitter std [s]")
    ap.add_argument("--spikes", type=float, default=0.0, metavar="P", help="probability of a spike per sample")
    ap.add_argument("--spike-sigma", type=float, default=30.0, help="spike size in noise_std")
    ap.add_argument("--bursts", type=float, default=0.0, metavar="P", help="probability per sample of a burst of 2-3")
    ap.add_argument("--rtol", type=float, default=1e-7)
    ap.add_argument("--method", default="RK45", choices=["RK45", "DOP853", "LSODA", "Radau", "BDF"])
    ap.add_argument("--truth", action="store_true", help="also write truth_* columns")
    ap.add_argument("-o", "--out", required=True)
    a = ap.parse_args(argv)
    try:
        if Path(a.out).suffix.lower() != ".csv":
            raise fx.SpecError(f"-o {a.out}: the output must be a .csv file")
        if not Path(a.out).resolve().parent.is_dir():
            raise fx.SpecError(f"-o {a.out}: no such directory")
        for name, v in (("--jitter", a.jitter), ("--spikes", a.spikes), ("--bursts", a.bursts)):
            if not 0 <= v < (1 if name in ("--spikes", "--bursts") else 0.5 / (a.rate or 1000.0)):
                raise fx.SpecError(f"{name} {v}: out of range")
        w0 = time.perf_counter()
        rec = generate(a.rig, a.effect, rate=a.rate, V0=a.V0, Tmax=a.Tmax, duration=a.duration, lead_in=a.lead_in,
                       steps=a.steps, cfg=fx.load_config(a.rig_file) if a.rig_file else None, seed=a.seed,
                       noise=not a.no_noise, jitter_s=a.jitter, spike_prob=a.spikes, burst_prob=a.bursts,
                       spike_sigma=a.spike_sigma, rtol=a.rtol, method=a.method)
        rec["meta"]["generate_wall_s"] = round(time.perf_counter() - w0, 3)
        csv_path, side = write(rec, a.out, truth=a.truth)
    except (fx.SpecError, OSError) as exc:
        print(f"refsim: {exc}", file=sys.stderr)
        return 2
    m = rec["meta"]
    print(f"wrote {csv_path} ({len(rec['t'])} samples at {m['rate_Hz']:g} Hz, channels "
          f"{', '.join(rec['channels'])}; {m['generate_wall_s']:.1f} s) and {side}; hidden: "
          f"{', '.join(e['effect'] for e in m['effects']) or 'nothing'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
