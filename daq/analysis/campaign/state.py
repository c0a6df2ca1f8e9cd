"""The drum campaign's state: what it runs (grid, programme, rig), every cell's status and result, on disk.

Why state and not a loop: a campaign is hours of unattended rig time. After each cell the state file
``OUT/campaign.json`` is rewritten atomically (temporary file + fsync + rename), so a kill at any
instant leaves either the old or the new state; a resume reads it back and runs the very same grid
(``CampaignCfg`` is stored with it). Also here: each cell's programme checked against the drive
(``cell_programme``) and each thrust row's copy of the rig config (``row_config``: on the simulated
rig the thrust is ``mechanics.thrust_N``).
"""

from __future__ import annotations

import datetime as _dt
import json
import os
from pathlib import Path
from typing import Literal

from pydantic import Field, ValidationError

from daq.analysis.paper002.programme import cell_ramp
from daq.config import config_text, load_rig
from daq.errors import InputError
from daq.io.files import atomic_path
from daq.ramps import check_limits, ramp_table
from daq.strict import Closed

FORMAT = "friction-daq drum campaign 1"
STATE = "campaign.json"


def utc_now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


# ----------------------------------------------------------------------------- state (pydantic, JSON)


class CampaignCfg(Closed):
    """What the campaign runs; stored in the state so a resume runs the very same grid."""

    rig: str = Field(description="rig config (id or TOML path) the thrust rows are copies of")
    thrusts_N: list[float]
    speeds_m_per_s: list[float]
    hold_s: float
    sweep_s: float
    time_scale: float
    sim: bool
    effects: list[str] = Field(default_factory=list)
    endpoint: str | None = None
    v_min_m_per_s: float
    cell_figures: bool = True


class CellCoef(Closed):
    value: float
    se: float | None
    identified: bool


class CellResult(Closed):
    coefficients: dict[str, CellCoef]
    R2: float
    rms: float
    n: int
    n_eff: float
    thrust_measured_N: float
    v_range_m_per_s: tuple[float, float]


class Cell(Closed):
    key: str
    thrust_N: float
    v0_m_per_s: float
    status: Literal["pending", "running", "interrupted", "done", "failed"] = "pending"
    attempts: int = 0
    recording: str | None = None
    ramp: str | None = None
    report: str | None = None
    started: str | None = None
    finished: str | None = None
    wall_s: float | None = None
    result: CellResult | None = None
    error: str | None = None
    partial: list[str] = Field(default_factory=list, description="recordings of interrupted attempts, kept aside")


class DaemonInfo(Closed):
    """The daemon (and simulated bench) this campaign started, so a resume after a kill can end them."""

    pid: int
    control: str
    sim_bench_pid: int | None = None
    sim_control: str | None = None
    thrust_N: float


class CampaignState(Closed):
    format: str = FORMAT
    cfg: CampaignCfg
    cells: list[Cell]
    daemon: DaemonInfo | None = Field(None, description="the daemon running now (None between rows)")
    daemons: list[DaemonInfo] = Field(default_factory=list, description="every daemon this campaign started")
    created: str
    updated: str
    runs: int = 0


def cell_key(thrust: float, v0: float) -> str:
    return f"P{thrust:g}N_v{v0 * 1e3:g}mm"


def save_state(path: Path, st: CampaignState) -> None:
    """Write the state atomically: a kill leaves the previous or the new file, never half of one."""

    st.updated = utc_now()
    with atomic_path(path) as tmp:
        with open(tmp, "w") as fh:
            fh.write(st.model_dump_json(indent=2))
            fh.flush()
            os.fsync(fh.fileno())


def load_state(path: Path) -> CampaignState:
    try:
        data = json.loads(path.read_text())
    except OSError as exc:
        raise InputError(str(path), "(file)", exc.strerror or str(exc)) from None
    except json.JSONDecodeError as exc:
        raise InputError(str(path), f"line {exc.lineno}", f"not JSON: {exc.msg}") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise InputError(str(path), "format", f"not a drum campaign state (expected {FORMAT!r})")
    try:
        return CampaignState.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        field = ".".join(str(x) for x in err["loc"]) or "(root)"
        raise InputError(str(path), field, err["msg"]) from None


def cell_programme(c: CampaignCfg, v0: float, rig=None):
    """One cell's Ramp, checked against the rig's drive limits (InputError naming --speeds)."""

    rig = rig or load_rig(c.rig)
    d = rig.drive
    if v0 > d.max_speed_m_per_s:
        raise InputError("--speeds", "--speeds", f"{v0:g} m/s exceeds the drive limit {d.max_speed_m_per_s} m/s")
    ramp = cell_ramp(v0, hold_s=c.hold_s, sweep_s=c.sweep_s, time_scale=c.time_scale,
                     max_accel=d.max_accel_m_per_s2, max_speed=d.max_speed_m_per_s)
    rt, rv = ramp_table(ramp, "--speeds")
    check_limits(rt, rv, d.max_speed_m_per_s, d.max_accel_m_per_s2, "--speeds")
    return ramp


def new_state(c: CampaignCfg) -> CampaignState:
    cells = [Cell(key=cell_key(p, v), thrust_N=p, v0_m_per_s=v) for p in c.thrusts_N for v in c.speeds_m_per_s]
    return CampaignState(cfg=c, cells=cells, created=utc_now(), updated=utc_now())


def row_config(c: CampaignCfg, thrust: float, out: Path) -> Path:
    """A copy of the rig config with mechanics.thrust_N = P (what a thrust row's daemon runs)."""

    cfg = load_rig(c.rig)
    cfg = cfg.model_copy(update={"mechanics": cfg.mechanics.model_copy(update={"thrust_N": float(thrust)})})
    path = out / "rigs" / f"{cfg.rig}-P{thrust:g}N.toml"
    path.parent.mkdir(parents=True, exist_ok=True)
    text = config_text(cfg)
    if not path.exists() or path.read_text() != text:
        path.write_text(text)
    return path
