"""Rig configuration files (rig_configs/*.toml), validated by pydantic.

Units live in field names (``k1_N_per_m``); unknown fields are errors so a
typo never silently falls back to a default. Values from the papers carry the
paper's number in a comment of the TOML file; chosen values say "chosen".

The ``[instruments]`` table holds one entry per instrument; its ``family`` says which of
the settings models below it validates into. Each family's settings are declared here,
once, and taken as they are by its driver (drivers/factory.py) and by its simulated
instrument (sim_backends/hardware.py); only the endpoint differs, applied with
``settings.with_endpoint(...)``. They live here, not in drivers/, because the rig config
is the layer below the drivers (tests/test_layering.py): every simulation and analysis
imports this module and must not pay for the transports (pyserial, python-can,
cantools: ~0.2 s of imports), and drivers/serial_stream.py imports this module for the
rig's channels. A driver's own config extends a family's settings with run-time-only
fields instead of repeating them (``MotorCfg``, ``ThermocoupleCfg``); the CAN and
binary-stream entries also name rig channels, which their drivers take in another form
(a DBC selection, frame slots with scales), so those drivers share only the link:
``CanBus`` (under ``CanBusCfg``) and ``StreamPort`` (under ``BinaryStreamCfg``).
Which driver and which simulator serve a family: drivers/families.py and
sim_backends/families.py.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal, Self, Union

import tomli_w
from pydantic import Field, ValidationError, field_validator, model_validator

from daq.physics.catalog import CATALOG

from .errors import DaqError, InputError, parse_toml, read_text
from .ramps import DECELERATION, DECELERATION_OLD
from .strict import Strict  # re-exported: models elsewhere import it from here

CONFIG_DIR = Path(__file__).resolve().parent.parent / "rig_configs"


class _FieldError(DaqError, ValueError):
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
    plausible_range: tuple[float, float] | None = Field(
        None, description="lowest and highest value the channel can read (e.g. the sensor's full scale); a data "
                          "file beyond it is refused (daq/io/plausible.py; default: a generous bound per unit)")

    @model_validator(mode="after")
    def _range_ordered(self) -> "ChannelCfg":
        if self.plausible_range is not None and not self.plausible_range[0] < self.plausible_range[1]:
            raise ValueError(f"plausible_range: lowest must be below highest, got {list(self.plausible_range)}")
        return self


class DriveCfg(Strict):
    """The belt (or drum surface) drive and its default programme."""

    kind: Literal["belt", "drum"]
    ramp: Literal["deceleration", "seed", "constant"]  # "seed": the old name of "deceleration", read as it
    V0_m_per_s: float = Field(gt=0.0)
    Tmax_s: float | None = Field(None, gt=0.0, description="deceleration ramp duration, paper 001 eq. (11)")
    max_speed_m_per_s: float = Field(gt=0.0)
    max_accel_m_per_s2: float = Field(gt=0.0)
    default_duration_s: float = Field(gt=0.0)

    @field_validator("ramp")
    @classmethod
    def _one_name_for_the_deceleration(cls, ramp: str) -> str:
        return DECELERATION_OLD if ramp == DECELERATION else ramp  # daq/ramps.py says why


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


# ---------------------------------------------------------------- instrument families' settings

Transport = Literal["serial", "can"]

#: which endpoint keys override which settings, per transport (``daq daemon --sim`` passes them)
ENDPOINT_KEYS: dict[Transport, tuple[str, ...]] = {"serial": ("url",), "can": ("interface", "channel", "bitrate")}


class InstrumentSettings(Strict):
    """What every family's entry has: its ``family`` tag (each subclass narrows it to one literal)."""

    family: str
    #: how the instrument is reached: a serial line (any pyserial URL) or a python-can bus
    transport: ClassVar[Transport] = "serial"

    def with_endpoint(self, endpoint: dict[str, Any]) -> Self:
        """These settings pointed at another endpoint (only this transport's keys are taken)."""
        update = {k: endpoint[k] for k in ENDPOINT_KEYS[self.transport] if k in endpoint}
        return self.model_copy(update=update) if update else self

    def rate_hz(self, sensor_rate_Hz: float) -> float | None:
        """Samples per second per channel (``sensor_rate_Hz``: the rig's sensor rate); None if not sampled."""
        return None


class SerialLine(Strict):
    """Where an instrument on a serial line is: its port (each family sets its own ``baudrate``)."""

    url: str = Field(min_length=1, description="pyserial URL or device path")


class MotorSettings(SerialLine, InstrumentSettings):
    """The belt/drum motor regulator on a serial line (docs/protocols/motor-regulator.md)."""

    family: Literal["motor-regulator"] = "motor-regulator"
    baudrate: int = Field(115200, gt=0)
    watchdog_ms: int = Field(500, ge=50, le=10000, description="regulator stops the belt after this silence")
    heartbeat_s: float = Field(0.1, gt=0, description="heartbeat period; must be well below watchdog_ms")
    enabled: bool = True


class CanBus(Strict):
    """Which python-can bus: any interface python-can knows, and its channel."""

    interface: str = Field(min_length=1, description="python-can interface, e.g. socketcan, pcan, kvaser, virtual")
    channel: str = Field(min_length=1)
    bitrate: int | None = Field(None, gt=0, description="bit/s; None leaves the interface's setting")


class CanSettings(CanBus, InstrumentSettings):
    """CAN sensors described by drivers/rig_sensors.dbc, on any python-can interface."""

    family: Literal["can-sensors"] = "can-sensors"
    channels: list[str] = Field(min_length=1, description="interchange channels carried on this bus")
    enabled: bool = True
    transport: ClassVar[Transport] = "can"

    def rate_hz(self, sensor_rate_Hz: float) -> float | None:
        return sensor_rate_Hz


class StreamPort(SerialLine):
    """The serial line of a high-rate binary sensor stream."""

    baudrate: int = Field(921_600, gt=0)


class StreamSettings(StreamPort, InstrumentSettings):
    """A high-rate binary sensor stream on a serial line (docs/protocols/serial-stream.md)."""

    family: Literal["serial-stream"] = "serial-stream"
    channels: list[str] = Field(min_length=1)
    enabled: bool = True

    def rate_hz(self, sensor_rate_Hz: float) -> float | None:
        return sensor_rate_Hz


class ThermocoupleSettings(SerialLine, InstrumentSettings):
    """The slow thermocouple meter on a serial line (docs/protocols/thermocouple.md)."""

    family: Literal["thermocouple"] = "thermocouple"
    baudrate: int = Field(9600, gt=0)
    poll_hz: float = Field(10.0, gt=0, le=50)
    enabled: bool = True

    def rate_hz(self, sensor_rate_Hz: float) -> float | None:
        return self.poll_hz


#: an [instruments] entry: the settings model its ``family`` names (a new family: its model, and here)
Instrument = Annotated[Union[MotorSettings, CanSettings, StreamSettings, ThermocoupleSettings],
                       Field(discriminator="family")]

# ---------------------------------------------------------------- the rigs


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
    driven: Literal["belt", "spring"] = Field(
        "belt", description="what the drive moves: 'belt' (paper 000: the belt under the masses, the chain's wall "
                            "fixed) or 'spring' (a spring-slider: the chain's far end moves, the track is fixed; seen "
                            "from the driver every mass feels + M dV/dt along x when the drive speed V changes)")


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
    instruments: dict[str, Instrument] = Field(default_factory=dict)
    seed_effects: dict[str, dict[str, float]] = Field(default_factory=dict)
    effects: dict[str, dict[str, float]] = Field(default_factory=dict)
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
                keys = {ps.key for form in spec.form_names() for ps in spec.params_for(self.rig, form or None)}
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


def user_rig_file(name_or_path: str | Path) -> str | None:
    """A user's rig file (anything with a suffix) as an absolute path, so a reference to it holds from any
    working directory; None for a built-in id (``brake-2dof``)."""
    return str(Path(name_or_path).resolve()) if Path(name_or_path).suffix else None


def rig_path(name_or_path: str | Path) -> Path:
    """The TOML file of a rig id or of a user's rig file; one InputError for an unknown id."""
    path = Path(name_or_path)
    if not path.suffix:
        path = CONFIG_DIR / f"{name_or_path}.toml"
        if not path.exists():
            raise InputError(str(name_or_path), "rig", f"unknown rig (known: {', '.join(rig_ids())})")
    return path


def load_rig(name_or_path: str | Path) -> RigConfig:
    """Load a rig by id (``brake-2dof``) or by path to a TOML file."""
    path = rig_path(name_or_path)
    return parse_rig(_rig_toml(path), str(path))


_RIG_TOML: dict[tuple[str, str], dict[str, Any]] = {}  # (path, the file's text) -> its TOML, parsed


def _rig_toml(path: Path) -> dict[str, Any]:
    """A rig file's TOML, parsed once per text of the file, handed out as a copy. Why: every fit builds its problem
    from the model's rig config, a proposal's scoring 60 times in 6 programmes, and tomllib took 1.7 ms of each
    2.1 ms load_rig: 3 % of that scoring (cProfile, 2026-11-28). Keyed by the text, not the file's modification time:
    reading it is cheap, and an edit within the clock's tick that keeps the size is still an edit."""
    text = read_text(path)
    key = (str(path), text)
    if key not in _RIG_TOML:
        if len(_RIG_TOML) >= 64:  # a daemon that lives for weeks beside edited rig files
            _RIG_TOML.clear()
        _RIG_TOML[key] = parse_toml(text, str(path))
    return copy.deepcopy(_RIG_TOML[key])


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
