"""Rig configuration files (rig_configs/*.toml), validated by pydantic.

Units live in field names (``k1_N_per_m``); unknown fields are errors so a
typo never silently falls back to a default. Values from the papers carry the
paper's number in a comment of the TOML file; chosen values say "chosen".
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal, Union

import tomli_w
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from daq.physics.effects import CATALOG

from .errors import InputError, parse_toml, read_text

CONFIG_DIR = Path(__file__).resolve().parent.parent / "rig_configs"


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class _FieldError(ValueError):
    """A model-level check that knows the field it is about, so the InputError can name it."""

    def __init__(self, field: str, message: str) -> None:
        self.field = field
        self.message = message
        super().__init__(f"{field}: {message}")


class ChannelCfg(Strict):
    """One measured channel: which instrument produces it and how it degrades the truth."""

    unit: str
    instrument: str
    description: str = ""
    noise_std: float = Field(0.0, ge=0.0, description="white noise, channel units")
    lsb: float = Field(0.0, ge=0.0, description="quantisation step, channel units (0 = none)")
    offset: float = 0.0
    rate_Hz: float | None = Field(None, gt=0.0, description="instrument update rate; held between updates")


class DriveCfg(Strict):
    """The belt (or drum surface) drive and its default programme."""

    kind: Literal["belt", "drum"]
    ramp: Literal["seed", "constant"]
    V0_m_per_s: float = Field(gt=0.0)
    Tmax_s: float | None = Field(None, gt=0.0, description="seed ramp duration, paper 001 eq. (11)")
    max_speed_m_per_s: float = Field(gt=0.0)
    max_accel_m_per_s2: float = Field(gt=0.0)
    default_duration_s: float = Field(gt=0.0)


class ContactCfg(Strict):
    """Contact environment read by the stateful effects (chosen values)."""

    v_stick_m_per_s: float = Field(gt=0.0)
    t_ambient_C: float
    r_thermal_K_per_W: float = Field(ge=0.0)
    tau_thermal_s: float = Field(gt=0.0)
    ambient_drift_K_per_s: float = 0.0
    force_rate_tau_s: float = Field(gt=0.0)
    stick_reset_tau_s: float = Field(gt=0.0)


class IntegratorCfg(Strict):
    dt_s: float = Field(gt=0.0, le=0.01)


class SensorsCfg(Strict):
    rate_Hz: float = Field(gt=0.0)


class MotorInstrument(Strict):
    """The belt/drum motor regulator on a serial line (docs/protocols/motor-regulator.md)."""

    family: Literal["motor-regulator"]
    url: str = Field(min_length=1, description="pyserial URL or device path")
    baudrate: int = Field(115200, gt=0)
    watchdog_ms: int = Field(500, ge=50, le=10000)
    heartbeat_s: float = Field(0.1, gt=0)
    enabled: bool = True


class CanInstrument(Strict):
    """CAN sensors described by drivers/rig_sensors.dbc, on any python-can interface."""

    family: Literal["can-sensors"]
    interface: str = Field(min_length=1, description="python-can interface, e.g. socketcan, pcan, kvaser, virtual")
    channel: str = Field(min_length=1)
    bitrate: int | None = Field(None, gt=0)
    channels: list[str] = Field(min_length=1, description="interchange channels carried on this bus")
    enabled: bool = True


class StreamInstrument(Strict):
    """A high-rate binary sensor stream on a serial line (docs/protocols/serial-stream.md)."""

    family: Literal["serial-stream"]
    url: str = Field(min_length=1)
    baudrate: int = Field(921600, gt=0)
    channels: list[str] = Field(min_length=1)
    enabled: bool = True


class ThermocoupleInstrument(Strict):
    """The slow thermocouple meter on a serial line (docs/protocols/thermocouple.md)."""

    family: Literal["thermocouple"]
    url: str = Field(min_length=1)
    baudrate: int = Field(9600, gt=0)
    poll_hz: float = Field(10.0, gt=0, le=50)
    enabled: bool = True


Instrument = Annotated[Union[MotorInstrument, CanInstrument, StreamInstrument, ThermocoupleInstrument],
                       Field(discriminator="family")]


class BrakeMechanics(Strict):
    M_kg: float = Field(gt=0)
    m_kg: float = Field(gt=0)
    J_kg_m2: float = Field(gt=0)
    r_m: float = Field(gt=0)
    k1_N_per_m: float = Field(ge=0)
    k2_N_per_m: float = Field(ge=0)
    k3_N_per_m: float = Field(ge=0)
    g_m_per_s2: float = Field(gt=0)


class BrakeFriction(Strict):
    law: Literal["brake-eq7"]
    mu0: float = Field(gt=0)
    gamma_s_per_m: float = Field(ge=0)
    alpha_s_per_m: float = Field(gt=0)
    beta: float = Field(ge=0, lt=1)


class DrumMechanics(Strict):
    I0_kg_m2: float = Field(gt=0)
    k_N_per_m: float = Field(gt=0)
    Rs_m: float = Field(gt=0)
    R_m: float = Field(gt=0)
    r0_m: float = Field(gt=0)
    m_kg: float = Field(gt=0)
    Rc_m: float = Field(gt=0)
    thrust_N: float = Field(gt=0)
    runout: float = Field(ge=0, lt=0.5)


class DrumFriction(Strict):
    law: Literal["drum-eq3"]
    A: float
    B_s_per_m: float = Field(gt=0)
    C_s_per_m: float = Field(ge=0)
    E: float
    sgn_eps_m_per_s: float = Field(gt=0)


class BeltMechanics(Strict):
    n_masses: int = Field(ge=1, le=3)
    mass_kg: float = Field(gt=0)
    stiffness_N_per_m: float = Field(gt=0)
    normal_force_N: float = Field(gt=0, description="friction unit F0 of paper 000 eq. (2)")


class BeltFriction(Strict):
    """Paper 000 piecewise-linear law, dimensionless (units of F0, w in sqrt(KM)/F0)."""

    law: Literal["pwl-000"]
    f_s0: float = Field(gt=0)
    alpha_drop: float = Field(gt=0)
    f_k0: float = Field(gt=0)
    k_fall: float = Field(ge=0)
    w_min: float = Field(gt=0)
    k_rise: float = Field(ge=0)


class RigBase(Strict):
    rig: str
    title: str
    paper: str
    drive: DriveCfg
    contact: ContactCfg
    integrator: IntegratorCfg
    sensors: SensorsCfg
    channels: dict[str, ChannelCfg]
    instruments: dict[str, Instrument] = {}
    seed_effects: dict[str, dict[str, float]] = {}
    effects: dict[str, dict[str, float]] = {}
    chosen: list[str] = Field(default_factory=list, description="which values are our choice, not the paper's")

    @model_validator(mode="after")
    def _instruments_consistent(self) -> "RigBase":
        carried: dict[str, str] = {}
        for name, inst in self.instruments.items():
            for ch in getattr(inst, "channels", []):
                if ch not in self.channels:
                    raise _FieldError(f"instruments.{name}.channels", f"{ch!r} is not a channel of this rig")
                if inst.enabled and ch in carried:
                    raise _FieldError(f"instruments.{name}.channels",
                                      f"{ch!r} is also carried by enabled instrument {carried[ch]!r}")
                if inst.enabled:
                    carried[ch] = name
        return self

    @model_validator(mode="after")
    def _effects_known(self) -> "RigBase":
        for table in ("seed_effects", "effects"):
            for name, values in getattr(self, table).items():
                spec = CATALOG.get(name)
                if spec is None:
                    raise _FieldError(f"{table}.{name}", f"unknown effect (catalog: {', '.join(CATALOG)})")
                if self.rig not in spec.rigs:
                    raise _FieldError(f"{table}.{name}", f"effect does not apply to {self.rig}")
                keys = {ps.key for ps in spec.params_for(self.rig)}
                for k in values:
                    if k not in keys:
                        raise _FieldError(f"{table}.{name}.{k}", f"unknown parameter (has {', '.join(sorted(keys))})")
        return self


class BrakeRig(RigBase):
    rig: Literal["brake-2dof"]
    mechanics: BrakeMechanics
    friction: BrakeFriction


class DrumRig(RigBase):
    rig: Literal["drum-pendulum"]
    mechanics: DrumMechanics
    friction: DrumFriction


class BeltRig(RigBase):
    rig: Literal["belt-ndof"]
    mechanics: BeltMechanics
    friction: BeltFriction


RigConfig = Union[BrakeRig, DrumRig, BeltRig]
_MODELS: dict[str, type[RigBase]] = {"brake-2dof": BrakeRig, "drum-pendulum": DrumRig, "belt-ndof": BeltRig}


def rig_ids() -> list[str]:
    return sorted(p.stem for p in CONFIG_DIR.glob("*.toml"))


def _field_path(loc: tuple[Any, ...]) -> str:
    return ".".join(str(x) for x in loc) or "(root)"


def parse_rig(data: dict[str, Any], source: str) -> RigConfig:
    """Validate a rig config mapping; raise InputError naming source and the first bad field."""
    rig = data.get("rig")
    model = _MODELS.get(rig) if isinstance(rig, str) else None
    if model is None:
        raise InputError(source, "rig", f"must be one of {', '.join(_MODELS)}, got {rig!r}")
    try:
        return model.model_validate(data)  # type: ignore[return-value]
    except ValidationError as exc:
        err = exc.errors()[0]
        cause = err.get("ctx", {}).get("error")
        if isinstance(cause, _FieldError):
            raise InputError(source, cause.field, cause.message) from None
        msg = err["msg"].removeprefix("Value error, ")
        raise InputError(source, _field_path(err["loc"]), msg) from None


def load_rig(name_or_path: str | Path) -> RigConfig:
    """Load a rig by id (``brake-2dof``) or by path to a TOML file."""
    path = Path(name_or_path)
    if not path.suffix:
        path = CONFIG_DIR / f"{name_or_path}.toml"
        if not path.exists():
            raise InputError(str(name_or_path), "rig", f"unknown rig (known: {', '.join(rig_ids())})")
    return parse_rig(parse_toml(read_text(path), str(path)), str(path))


def config_for_recording(stored: object, source: str, override: str | Path | None, rig: str,
                         what: str) -> RigConfig:
    """The rig config an analysis of a recording uses: ``override`` (id or TOML), else the config the
    recording carries (its own geometry and parameters: ``stored`` TOML text), else the built-in one of
    ``rig``. A config of another rig is one InputError: ``what`` needs a ``rig`` recording."""
    if override:
        cfg = load_rig(override)
    elif isinstance(stored, str):
        cfg = parse_rig(parse_toml(stored, f"{source} (rig_config)"), f"{source} (rig_config)")
    else:
        cfg = load_rig(rig)
    if cfg.rig != rig:
        raise InputError(source, "rig", f"{what} a {rig} recording, this is from {cfg.rig}")
    return cfg


def config_text(cfg: RigConfig) -> str:
    """The config as TOML text, stored with every recording so a run can be reproduced."""

    return tomli_w.dumps(cfg.model_dump(mode="json", exclude_none=True))
