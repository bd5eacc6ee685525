"""Bench configuration: one TOML file per bench (documented in bench.example.toml).

`load_config(path)` reads, checks and builds everything a run needs (site, table
limits and register map, the compiled IMU frame layout, the schedules, the simulator's
truth) so that a bad file fails before any hardware moves, with one `ConfigError`
line ``file:line: key: message``. Each key's accepted name, default and range come from the
key table `bench.config.keys` (docs/reference/configuration.md is generated from it; a message
names the range); the file, a register map and a DBC are read only when
they are regular files of at most 1 MiB. Relative paths inside the file (register map, DBC,
schedule files) start at the file's folder; `[output] folder` starts at the current
directory at run time.
"""

from __future__ import annotations

import dataclasses
import math
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can.interfaces
import numpy as np

from bench.acceptance.limits import AcceptanceLimits
from bench.config.acceptance import ACCEPTANCE_KEYS, acceptance_limits
from bench.config.chamber import CHAMBER_KEYS, ChamberConfig, chamber_config
from bench.config.device import SIM_URL, url_and_dialect
from bench.config.higher_order import HIGHER_ORDER_KEYS, sim_higher_order
from bench.config.keys import (
    MAX_ACC_STABILITY_UG,
    MAX_BLACK_BOX_ARCSEC,
    MAX_GYRO_STABILITY_DPH,
    SIM_IMU_RANGES,
    allowed,
    declared,
    integer,
    number,
    optional_number,
)
from bench.config.lab import LAB_KEYS, LabConfig, lab_config
from bench.config.model import model_terms
from bench.config.reader import ConfigError, Located, Table, describe, parse_toml, read_text, show, suggest
from bench.config.register_map import TABLE_MAP, load_register_map, register_map_value
from bench.config.rig import RigIdentity
from bench.config.thermal import THERMAL_KEYS, sim_thermal
from bench.config.thermal_plan import check_against_chamber, thermal_plan
from bench.config.units import imu_units
from bench.errors import InputError
from bench.model.earth import HANGZHOU_LATITUDE_DEG, Site
from bench.model.families import BODY_AXES, SENSOR_AXES, family_of
from bench.model.higher_order import HigherOrderTerms
from bench.model.imu import ImuCoefficients, NoiseModel, default_sim_imu, default_sim_si_imu
from bench.model.noise_result import NoiseResult
from bench.model.table_prior import (
    FRAME_KEYS,
    TablePrior,
    TablePriorError,
    from_datasheet,
    load_check,
    pointing_sigmas_arcsec,
)
from bench.model.thermal import ImuThermal
from bench.model.units import ARCSEC
from bench.plan.compiler import ORDERS, PlanTiming
from bench.plan.thermal import ThermalPlan
from drivers.errors import DeviceConfigError
from drivers.imu import SHIPPED_LAYOUTS, ImuFrameSpec, ImuLayout
from drivers.imu.slcan_bus import SLCAN_CLIENTS
from drivers.turntable import DIALECTS, FRAMES, AxisLimits, TurntableLimits, check_url_dialect
from drivers.turntable.modbus_map import RegisterMap
from schedules import Schedule, ScheduleError, builtin_names, resolve_schedule
from schedules.tomlinput import MAX_FILE_BYTES
from schedules.tomllines import locate_lines

FORMAT = "turntable-bench/config"
VERSION = 1
_NOISE_FIELDS = tuple(f.name for f in dataclasses.fields(NoiseModel))
#: an observation (a dwell) holds at least this many IMU samples at `imu.rate_hz`
MIN_SAMPLES_PER_DWELL = 2

__all__ = ["FORMAT", "ORDERS", "SIM_CONFIG_TOML", "SIM_URL", "VERSION", "BenchConfig", "ChamberConfig", "ConfigError",
           "ImuConfig", "ImuIdentity", "OutputConfig", "PlanConfig", "SimConfig", "SiteConfig", "TableConfig",
           "default_sim_config", "load_config", "load_register_map", "parse_config", "ImuNoise"]


@dataclass(frozen=True)
class SiteConfig:
    """[site]: where the table stands; `site` is the built `bench.model.earth.Site`."""

    latitude_deg: float
    height_m: float
    local_g_mps2: float | None
    site: Site
    #: 1-sigma of the configured latitude and gravity (the budget's site parts); defaults:
    #: 0.001 deg (about 100 m), gravity 1e-5 m/s^2 when measured (local_g_mps2), else 5e-4 m/s^2
    #: (the normal gravity formula ignores anomalies of up to about 50 mGal)
    latitude_sigma_deg: float = 0.001
    gravity_sigma_mps2: float = 5e-4


@dataclass(frozen=True)
class TableConfig:
    """[table]: the controller, its limits and (Modbus) register map."""

    url: str
    dialect: str
    timeout_s: float
    retries: int
    settle_tolerance_deg: float
    poll_s: float
    limits: TurntableLimits
    register_map: RegisterMap | None  # modbus only; None = the documented default map
    #: what the lab knows of the table's pointing error (`pointing_accuracy_arcsec`,
    #: `orthogonality_arcsec`, `check`): the budget's turntable part; None = not known
    pointing: TablePrior | None = None
    #: 1-sigma error of each turn's angle (end minus start: the table's position repeatability at both
    #: ends, the readback's resolution), arcsec: the budget's turn-angle part; None = not known
    turn_angle_error_arcsec: float | None = None

    @property
    def is_sim(self) -> bool:
        """url "sim": the simulated table served over loopback in `dialect`."""
        return self.url == SIM_URL


@dataclass(frozen=True)
class ImuIdentity:
    """[imu.identity]: what is being calibrated (recorded; stabilities feed the solver)."""

    model: str = ""
    serial: str = ""
    gyro_bias_stability_dph: float | None = None
    acc_bias_stability_ug: float | None = None
    #: correlation time of the bias instability (a first-order Gauss-Markov bias), s
    bias_correlation_time_s: float | None = None
    #: 1-sigma relative error of the uncalibrated x/y accelerometers against z (their common scale error and
    #: their axes' rotation about z): the table check's conversion part; None: its default 1e-3
    acc_xy_to_z_uncertainty: float | None = None


@dataclass(frozen=True)
class ImuNoise:
    """[imu] noise = "FILE": a `bench noise` result whose bias instabilities the solve uses."""

    path: Path
    gyro_bias_stability_dph: float    # the largest of the three gyros'
    acc_bias_stability_ug: float      # the largest of the three accelerometers'


@dataclass(frozen=True)
class ImuConfig:
    """[imu]: the CAN bus and the compiled frame layout."""

    interface: str
    channel: str | int
    bitrate: int | None
    fd: bool
    dbc: Path
    rate_hz: float
    spec: ImuFrameSpec
    layout: ImuLayout
    bus_options: dict = field(default_factory=dict)
    identity: ImuIdentity = ImuIdentity()
    noise: ImuNoise | None = None     # [imu] noise = "FILE"; its stabilities replace the identity's
    #: [imu] layout: the shipped layout's name ("classic", "packed", "fd"); None: the IMU's own `dbc`
    layout_name: str | None = "classic"
    #: [imu] slcan_client: who reads an SLCAN adapter: "bench" (the bulk reader) or "python-can"
    slcan_client: str = "bench"
    #: an [[imu]] entry's mounting on the fixture: the rotation `C_i^b` from the fixture (inner frame) to the unit's
    #: body axes, as rows; None: a single [imu], whose body axes are the fixture's
    mounting: tuple[tuple[float, ...], ...] | None = None
    mounting_name: str = ""           # the face it names ("x-up"), or "matrix"; "" for a single [imu]
    #: an [[imu]] entry's lever_arm_mm: the unit's place from the table's rotation centre, fixture axes, mm; None:
    #: not given (the sim places it at the centre, the solve takes nothing out)
    lever_arm_mm: tuple[float, float, float] | None = None
    #: an [[imu]] entry's id_offset: added to every frame id of its layout (`layout` has it added already)
    id_offset: int = 0
    #: [imu.rig]: the `bench sim rig` the file was written for (valid only while it runs); None: not a rig's
    rig: RigIdentity | None = None

    def bus_kwargs(self) -> dict:
        """Keyword arguments for `drivers.imu.receiver.open_bus` (python-can's `can.Bus(**kwargs)`, with
        `slcan_client` for an SLCAN adapter)."""
        kwargs: dict = {"interface": self.interface, "channel": self.channel, "fd": self.fd}
        if self.bitrate is not None:
            kwargs["bitrate"] = self.bitrate
        if self.interface == "slcan":
            kwargs["slcan_client"] = self.slcan_client
        return {**kwargs, **self.bus_options}


@dataclass(frozen=True)
class PlanConfig(PlanTiming):
    """[plan]: the loaded schedules and the timing of moves, dwells and turns (a `PlanTiming`)."""

    positions: Schedule | None = field(default=None, kw_only=True)
    # every step's revolutions already overridden by `revolutions`
    rotations: Schedule | None = field(default=None, kw_only=True)
    order: str = field(default="optimal", kw_only=True)
    #: the verification schedule (`[plan] verification`): run after the calibration, None: none
    verification: Schedule | None = field(default=None, kw_only=True)
    #: `[plan] temperatures_c` and `[plan.soak]`: a calibration at each chamber temperature, None: one, no chamber
    thermal: ThermalPlan | None = field(default=None, kw_only=True)


@dataclass(frozen=True)
class OutputConfig:
    """[output]: where runs are written, and how their logs are chunked."""

    folder: Path  # relative paths start at the current directory at run time
    #: the recorder closes a log chunk every this many seconds of run clock; None: its default
    chunk_run_interval_s: float | None = None


@dataclass(frozen=True)
class SimConfig:
    """[sim]: the simulated world (`--sim`, table url "sim"): black box, noise, true IMU."""

    seed: int
    black_box_arcsec: float | tuple  # RMS, or the 3x3 angles as written
    black_box_rad: np.ndarray        # (3, 3): rows o0, m0, i0; columns alpha, beta, gamma
    noise: NoiseModel
    imu: ImuCoefficients             # the simulated IMU's true coefficients
    imu_overrides: dict = field(default_factory=dict)  # canonical name -> display-unit value as written
    #: [sim.imu.thermal]: `imu` holds at its reference temperature; None: no temperature dependence
    thermal: ImuThermal | None = None
    #: [sim.imu.higher_order]: the errors beyond the 30 coefficients; None: none (the table absent)
    higher_order: HigherOrderTerms | None = None


@dataclass(frozen=True)
class BenchConfig:
    """One checked bench configuration; `source_text` is the TOML as read (for the run log)."""

    site: SiteConfig
    table: TableConfig
    imu: ImuConfig
    plan: PlanConfig
    output: OutputConfig
    sim: SimConfig
    source_text: str = field(repr=False)
    path: Path | None = None  # None when parsed from a string
    acceptance: AcceptanceLimits = field(default_factory=AcceptanceLimits)  # [acceptance]: limits of the verdict
    chamber: ChamberConfig | None = None  # [chamber]: the thermal chamber, None: none
    lab: LabConfig = field(default_factory=LabConfig)  # [lab]: the lab, customer, item and equipment
    #: the [[imu]] entries of a run of several units (`imu` is the first: the run's reference unit); () for [imu]
    units: tuple[ImuConfig, ...] = ()
    #: [model] terms: the higher-order families the solve estimates beyond the 30 (("auto",): the data choose)
    model_terms: tuple[str, ...] = ()
    #: [run] on_unit_failure: "continue" (a failed unit is dropped, the others finish) or "stop" (the run stops)
    on_unit_failure: str = "continue"

    @property
    def several(self) -> bool:
        """The configuration has [[imu]] entries (each unit its own topics, solve and outputs)."""
        return bool(self.units)


# --- sections -----------------------------------------------------------------------

def _site(t: Table) -> SiteConfig:
    latitude_deg = number(t, "site", "latitude_deg")
    height_m = number(t, "site", "height_m")
    local_g = optional_number(t, "site", "local_g_mps2")  # Site's plausibility range
    latitude_sigma = number(t, "site", "latitude_sigma_deg")
    gravity_sigma = number(t, "site", "gravity_sigma_mps2", 1e-5 if local_g is not None else 5e-4)
    return SiteConfig(latitude_deg, height_m, local_g, Site(latitude_deg, height_m, local_g), latitude_sigma,
                      gravity_sigma)


def _axis_limits(t: Table) -> AxisLimits:
    section = "table.limits.<frame>"
    min_deg, max_deg = (optional_number(t, section, key) for key in ("min_deg", "max_deg"))
    if min_deg is not None and max_deg is not None and not min_deg < max_deg:
        raise t.error("max_deg", f"must be above min_deg ({min_deg:g} deg), got {max_deg:g}")
    return AxisLimits(min_deg, max_deg, number(t, section, "max_rate_dps"), number(t, section, "max_accel_dps2"))


def _table(t: Table) -> TableConfig:
    url, dialect = url_and_dialect(t, "table", DIALECTS, check_url_dialect,
                                   lambda name: f"unknown dialect {show(name)}" + suggest(name, DIALECTS).replace(
                                       " (known:", " (known dialects:"))
    timeout_s = number(t, "table", "timeout_s")
    retries = integer(t, "table", "retries")
    assert retries is not None
    tolerance_deg = number(t, "table", "settle_tolerance_deg")
    poll_s = number(t, "table", "poll_s")
    limits_table = t.table("limits", allowed("table.limits"))
    outer, middle, inner = (_axis_limits(limits_table.table(frame, allowed("table.limits.<frame>")))
                            for frame in FRAMES)
    limits = TurntableLimits((outer, middle, inner))
    register_map = _register_map(t, dialect)
    pointing = _pointing(t)
    turn_angle = optional_number(t, "table", "turn_angle_error_arcsec")
    return TableConfig(url, dialect, timeout_s, retries, tolerance_deg, poll_s, limits, register_map, pointing,
                       turn_angle)


def _pointing(t: Table) -> TablePrior | None:
    """[table] pointing_accuracy_arcsec (a number, or {outer, middle, inner}), orthogonality_arcsec, check."""
    pointing: float | dict[str, float] | None = None
    if t.has("pointing_accuracy_arcsec"):
        if isinstance(t.get("pointing_accuracy_arcsec"), dict):
            frames = t.table("pointing_accuracy_arcsec", allowed("table.pointing_accuracy_arcsec"))
            pointing = {f: number(frames, "table.pointing_accuracy_arcsec", f) for f in FRAME_KEYS}
        else:
            pointing = number(t, "table", "pointing_accuracy_arcsec")
    orthogonality = optional_number(t, "table", "orthogonality_arcsec")
    if orthogonality is not None and pointing is None:
        raise t.error("orthogonality_arcsec", "needs pointing_accuracy_arcsec too (the frames' zero offsets)")
    if t.has("check"):
        path = t.file("check")
        if not t.is_file("check", path):
            raise t.error("check", f"no such table-check result file {show(str(path))} (a *.table-check.json "
                                   "from `bench check-table`)")
        prior = None if pointing is None else pointing_sigmas_arcsec(pointing, orthogonality)
        try:
            return load_check(path, prior)
        except TablePriorError as exc:
            raise t.error("check", str(exc)) from None
    return None if pointing is None else from_datasheet(pointing, orthogonality)


def _register_map(t: Table, dialect: str) -> RegisterMap | None:
    """`register_map = "file.toml"` (a file holding a [modbus] table) or an inline [table.modbus]."""
    return register_map_value(t, dialect, "table", TABLE_MAP)


def _imu(t: Table) -> ImuConfig:
    interface = t.string("interface", nonempty=True)
    if interface not in can.interfaces.VALID_INTERFACES:
        raise t.error("interface", f"unknown python-can interface {show(interface)}"
                      + suggest(interface, sorted(can.interfaces.VALID_INTERFACES)))
    channel = t.get("channel")
    if isinstance(channel, bool) or not isinstance(channel, (str, int)) or channel == "":
        raise t.error("channel", f"must be a non-empty string or a whole number, got {describe(channel)}")
    if isinstance(channel, int):
        t.integer("channel", ge=0, le=65535)
    bitrate = integer(t, "imu", "bitrate")
    fd = t.boolean("fd", declared("imu", "fd").default)
    rate_hz = number(t, "imu", "rate_hz")
    layout_name = t.string("layout", choices=list(SHIPPED_LAYOUTS)) if t.has("layout") else None
    if layout_name is not None and t.has("dbc"):
        raise t.error("layout", "names a shipped layout; an IMU's own DBC file goes in `dbc` instead: give one")
    if t.has("dbc"):
        dbc = t.file("dbc")
        _check_dbc(t, dbc)
    else:
        layout_name = layout_name or ("fd" if fd else "classic")
        dbc = SHIPPED_LAYOUTS[layout_name][0]
    signals = t.get("signals", None)
    if signals is None:
        spec = SHIPPED_LAYOUTS[layout_name or ("fd" if fd else "classic")][1]
    else:
        if not isinstance(signals, dict):
            raise t.error("signals", f"must be a table ([imu.signals]), got {describe(signals)}")
        try:
            spec = ImuFrameSpec.from_dict(signals)
        except DeviceConfigError as exc:
            raise t.error("signals", str(exc)) from exc
    blame = "dbc" if t.has("dbc") else ("signals" if t.has("signals") else ("layout" if t.has("layout") else None))
    try:
        layout = ImuLayout.from_dbc(dbc, spec)
    except DeviceConfigError as exc:
        raise t.error(blame, str(exc)) from exc
    if not fd:
        for message in layout.messages:
            if message.is_fd or message.length > 8:
                raise t.error(blame or "fd", f"message {message.name} of {dbc.name} is a CAN FD frame "
                              f"({message.length} bytes); set imu.fd = true")
    bus_options = t.get("bus_options", {})
    if not isinstance(bus_options, dict):
        raise t.error("bus_options", f"must be a table ([imu.bus_options]), got {describe(bus_options)}")
    for key in bus_options:
        if key in ("interface", "channel", "bitrate", "fd", "bustype"):
            raise t.doc.error(t.path + ("bus_options", key), f"set imu.{key.replace('bustype', 'interface')} "
                              "instead of passing it in bus_options")
    ident = t.table("identity", allowed("imu.identity"))
    identity = ImuIdentity(ident.string("model", declared("imu.identity", "model").default),
                           ident.string("serial", declared("imu.identity", "serial").default),
                           *(optional_number(ident, "imu.identity", name)
                             for name in ("gyro_bias_stability_dph", "acc_bias_stability_ug",
                                          "bias_correlation_time_s", "acc_xy_to_z_uncertainty")))
    noise = _imu_noise(t) if t.has("noise") else None
    slcan_client = t.string("slcan_client", declared("imu", "slcan_client").default, choices=SLCAN_CLIENTS)
    rig = None
    if t.has("rig"):
        r = t.table("rig", allowed("imu.rig"))
        rig = RigIdentity(r.string("id", nonempty=True), r.integer("pid", None, ge=1),
                          r.string("started_utc", declared("imu.rig", "started_utc").default))
    return ImuConfig(interface, channel, bitrate, fd, Path(dbc), rate_hz, spec, layout, bus_options, identity, noise,
                     layout_name, slcan_client, rig=rig)


def _imu_noise(t: Table) -> ImuNoise:
    """`noise = "FILE"`: a noise result (`bench noise`) with a bias instability for the gyros and the accelerometers."""
    path = t.file("noise")
    if not t.is_file("noise", path):
        if path.exists():  # a directory, a device such as /dev/zero, a FIFO
            raise t.error("noise", f"{show(str(path))} is not a regular file (a *.noise.json from `bench noise`)")
        raise t.error("noise", f"no such noise result file {show(str(path))}")
    try:
        result = NoiseResult.load(path)
    except OSError as exc:
        raise t.error("noise", f"cannot read {show(str(path))}: {exc.strerror or exc}") from None
    except InputError as exc:   # not a noise result, not JSON, a number out of range, too large
        raise t.error("noise", str(exc).removeprefix(f"{path}: ")) from None
    values = []
    for what, value, name, high in (("gyro", result.gyro_bias_stability_dph, "gyro_bias_stability_dph",
                                     MAX_GYRO_STABILITY_DPH),
                                    ("accelerometer", result.acc_bias_stability_ug, "acc_bias_stability_ug",
                                     MAX_ACC_STABILITY_UG)):
        if value is None:
            raise t.error("noise", f"{show(str(path))} holds no {what} bias instability")
        if not 0 < value <= high:
            raise t.error("noise", f"{show(str(path))}: {what} bias instability {value:g} is outside the range of "
                                   f"imu.identity.{name} (> 0 and <= {high:g})")
        values.append(value)
    return ImuNoise(path, values[0], values[1])


def _check_dbc(t: Table, dbc: Path) -> None:
    """Read a DBC only when it is a regular file of at most 1 MiB (/dev/zero would fill the memory)."""
    try:
        status = dbc.stat()
    except OSError as exc:
        raise t.error("dbc", f"cannot read the DBC file {show(str(dbc))}: {exc.strerror or exc}") from None
    if not stat.S_ISREG(status.st_mode):
        raise t.error("dbc", f"cannot read the DBC file {show(str(dbc))}: not a regular file")
    if status.st_size > MAX_FILE_BYTES:
        raise t.error("dbc", f"cannot read the DBC file {show(str(dbc))}: larger than the "
                             f"{MAX_FILE_BYTES >> 20} MiB limit for input files")


def _schedule(t: Table, key: str, kind: str, revolutions: int | None) -> Schedule | None:
    name = t.string(key, "").strip()
    if not name:
        return None
    try:
        if name in builtin_names():
            schedule = resolve_schedule(name)
        else:
            path = t.resolve(key, name)
            if not t.is_file(key, path):
                if path.exists():  # a directory, a device such as /dev/zero, a FIFO
                    raise t.error(key, f"{show(str(path))} is not a regular file (a schedule file or one of the "
                                       f"builtins: {', '.join(builtin_names())})")
                raise t.error(key, f"no builtin schedule {show(name)} and no such file {show(str(path))}"
                              + suggest(name, builtin_names()).replace(" (known:", " (builtins:"))
            schedule = resolve_schedule(str(path))
    except ScheduleError as exc:  # it names the schedule file, line and field already
        raise ConfigError(exc.path, exc.line, exc.field, exc.message) from exc
    # a "static" schedule (one long dwell: `bench noise`) runs as a positions schedule
    if schedule.kind != kind and not (kind == "positions" and schedule.kind == "static"):
        raise t.error(key, f"schedule {schedule.name!r} is a {schedule.kind!r} schedule; plan.{key} needs "
                      f"a {kind!r} schedule")
    if revolutions is not None and schedule.rotations:
        schedule = dataclasses.replace(schedule, rotations=tuple(
            dataclasses.replace(step, revolutions=revolutions) for step in schedule.rotations))
    return schedule


def _plan(t: Table, limits: TurntableLimits) -> PlanConfig:
    revolutions = integer(t, "plan", "revolutions")
    order = t.string("order", declared("plan", "order").default, choices=ORDERS)
    positions = _schedule(t, "positions", "positions", revolutions)
    rotations = _schedule(t, "rotations", "rotations", revolutions)
    if positions is None and rotations is None:
        raise t.error(None, "the plan needs a positions schedule, a rotations schedule or both "
                            "(plan.positions / plan.rotations)")
    if positions is not None and positions.kind == "static" and rotations is not None:
        raise t.error("rotations", f"plan.positions {positions.name!r} is a static noise recording (one dwell, "
                                   "analysed by `bench noise`): leave plan.rotations out")
    values = {name: number(t, "plan", name) for name in ("dwell_s", "settle_s", "move_rate_dps", "move_accel_dps2",
                                                         "turn_rate_dps", "turn_accel_dps2", "rest_s")}
    # Moves drive every axis; turns only the frames the rotation schedule turns.
    turned = sorted({step.frame_index for step in rotations.rotations}) if rotations else []
    for key, attr, frames in (("move_rate_dps", "max_rate_dps", range(3)),
                              ("move_accel_dps2", "max_accel_dps2", range(3)),
                              ("turn_rate_dps", "max_rate_dps", turned),
                              ("turn_accel_dps2", "max_accel_dps2", turned)):
        for frame in frames:
            limit = getattr(limits.axes[frame], attr)
            if values[key] > limit:
                unit = "deg/s" if key.endswith("_dps") else "deg/s^2"
                raise t.error(key, f"{values[key]:g} {unit} exceeds the {FRAMES[frame]} axis limit {limit:g} "
                                   f"{unit} (table.limits.{FRAMES[frame]}.{attr})")
    verification = _schedule(t, "verification", "verification", None)
    thermal = thermal_plan(t)
    if thermal is not None and positions is not None and positions.kind == "static":
        raise t.error("temperatures_c", f"plan.positions {positions.name!r} is a static noise recording: a "
                                        "calibration over temperature needs calibration schedules")
    if thermal is not None and verification is not None:
        raise t.error("verification", "a verification run after a calibration over temperature is not supported "
                                      "yet: leave plan.verification out with plan.temperatures_c")
    return PlanConfig(positions=positions, rotations=rotations, revolutions=revolutions, order=order,
                      verification=verification, thermal=thermal, **values)


def _black_box(t: Table, seed: int) -> tuple[float | tuple, np.ndarray]:
    value = t.get("black_box_arcsec", declared("sim", "black_box_arcsec").default)
    if isinstance(value, list):
        rows = []
        if len(value) != 3:
            raise t.error("black_box_arcsec", f"must be 3 rows (o0, m0, i0) of 3 angles, got {len(value)} rows")
        for i, row in enumerate(value):
            # Compared before any float(): a 400-digit integer compares exactly; NaN fails.
            if not (isinstance(row, list) and len(row) == 3
                    and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                            and -MAX_BLACK_BOX_ARCSEC <= v <= MAX_BLACK_BOX_ARCSEC for v in row)):
                raise t.doc.error(t.path + ("black_box_arcsec", i),
                                  f"must be 3 finite angles [alpha, beta, gamma] in arcsec, got {show(row)} "
                                  f"(allowed: -{MAX_BLACK_BOX_ARCSEC:g} <= angle <= {MAX_BLACK_BOX_ARCSEC:g} "
                                  "arcsec)")
            rows.append(tuple(float(v) for v in row))
        return tuple(rows), np.array(rows) * ARCSEC
    rms_arcsec = number(t, "sim", "black_box_arcsec")
    return rms_arcsec, np.random.default_rng(seed).standard_normal((3, 3)) * rms_arcsec * ARCSEC


def _noise(t: Table, si_outputs: bool = False) -> NoiseModel:
    """[sim] noise; `si_outputs`: the IMU sends physical units (sbg-ecan), whose default is the MEMS IMU's noise
    and which its output format quantises (the integer-count `quantise` does not apply)."""
    on = NoiseModel.mems() if si_outputs else NoiseModel()
    value = t.get("noise", declared("sim", "noise").default)
    if isinstance(value, bool):
        return on if value else NoiseModel.off()
    n = t.table("noise", allowed("sim.noise"))
    enabled = n.boolean("enabled", declared("sim.noise", "enabled").default)
    base = on if enabled else NoiseModel.off()
    if si_outputs and n.get("quantise", False) is True:
        raise n.error("quantise", "integer counts do not apply to an IMU sending physical units (imu.layout = "
                                  "\"sbg-ecan\"): its output format's resolution quantises it")
    changes: dict[str, Any] = {}      # field -> value: a float level, or the bool `quantise`
    for name in _NOISE_FIELDS:
        if not n.has(name):
            continue
        if name == "quantise":
            changes[name] = n.boolean(name)
        elif not enabled:
            raise n.error(name, "noise levels need sim.noise.enabled = true")
        else:
            changes[name] = number(n, "sim.noise", name)
    return dataclasses.replace(base, **changes)


def _sim_imu(t: Table, si_outputs: bool = False) -> tuple[ImuCoefficients, dict, ImuThermal | None,
                                                          HigherOrderTerms | None]:
    s = t.table("imu", allowed("sim.imu"))
    thermal = None
    if s.has("thermal"):
        ranges = {family: (high, unit) for family, (_low, high, unit) in SIM_IMU_RANGES.items()}
        thermal = sim_thermal(s.table("thermal", THERMAL_KEYS), ranges)
    higher_order = sim_higher_order(s.table("higher_order", HIGHER_ORDER_KEYS)) if s.has("higher_order") else None
    overrides = {}
    for name in s.data:
        if name in ("thermal", "higher_order"):
            continue
        low, high, unit = SIM_IMU_RANGES[family_of(name)]
        overrides[name] = s.number(name, gt=low, ge=None if low is not None else -high, le=high, unit=unit)
    values = {**(default_sim_si_imu() if si_outputs else default_sim_imu()).to_canonical(), **overrides}
    # Direction-cosine rows are unit vectors: a row with overrides gets its diagonal
    # from its off-diagonals, unless the diagonal is given too (then it must fit).
    for prefix in ("Eg", "Ea"):
        for i, sensor in enumerate(SENSOR_AXES):
            row = [f"{prefix}_{axis}{sensor}" for axis in BODY_AXES]
            if not any(name in overrides for name in row):
                continue
            diag = row[i]
            if diag in overrides:
                norm = math.sqrt(sum(values[name] ** 2 for name in row))
                if abs(norm - 1.0) > 1e-6:
                    raise s.error(diag, f"the row {', '.join(row)} must have unit length, has {norm:.9g} "
                                        f"(leave {diag} out and it follows from the others)")
                values.update({name: values[name] / norm for name in row})
            else:
                rest = 1.0 - sum(values[name] ** 2 for name in row if name != diag)
                if not rest > 0:
                    raise s.error(next(name for name in row if name in overrides),
                                  f"the off-diagonal direction cosines of {prefix}_*{sensor} leave no unit row")
                values[diag] = math.copysign(math.sqrt(rest), values[diag])
    return ImuCoefficients.from_canonical(values), overrides, thermal, higher_order


def _sim(t: Table, si_outputs: bool = False) -> SimConfig:
    """[sim]; `si_outputs`: the IMU's layout sends physical units per second (sbg-ecan), so the simulated IMU
    defaults to the MEMS one (`default_sim_si_imu`, `NoiseModel.mems`)."""
    seed = integer(t, "sim", "seed")
    assert seed is not None
    written, black_box_rad = _black_box(t, seed)
    imu, overrides, thermal, higher_order = _sim_imu(t, si_outputs)
    return SimConfig(seed, written, black_box_rad, _noise(t, si_outputs), imu, overrides, thermal, higher_order)


# --- entry points -------------------------------------------------------------------

def parse_config(text: str, source: str = "<string>", base_dir: str | Path | None = None) -> BenchConfig:
    """Parse and check configuration TOML `text`; `source` names it in errors; relative
    paths start at `base_dir` (default: the current directory)."""
    doc = parse_toml(text, source)
    located = Located(source, locate_lines(text), Path.cwd() if base_dir is None else Path(base_dir))
    root = Table(located, (), doc, allowed(""))
    fmt = root.string("format")
    if fmt != FORMAT:
        raise root.error("format", f"expected {FORMAT!r}, got {show(fmt)}")
    version = root.get("version")
    if isinstance(version, bool) or version != VERSION:
        raise root.error("version", f"unsupported version: must be {VERSION}, got {describe(version)}")
    site = _site(root.table("site", allowed("site"), required=True))
    table = _table(root.table("table", allowed("table"), required=True))
    units: tuple[ImuConfig, ...] = ()
    if isinstance(root.data.get("imu"), list):          # [[imu]]: several units
        units = imu_units(root, allowed("imu"), _imu)
        imu = units[0]
    else:
        imu_table = root.table("imu", allowed("imu"), required=True)
        for key in ("mounting", "id_offset", "lever_arm_mm"):
            if imu_table.has(key):
                raise imu_table.error(key, "belongs to an [[imu]] entry (a run of several units, even of one): a "
                                           "single [imu] is the fixture's own axes")
        imu = _imu(imu_table)
    plan_table = root.table("plan", allowed("plan"), required=True)
    plan = _plan(plan_table, table.limits)
    slowest = min(unit.rate_hz for unit in (imu, *units))
    if plan.dwell_s * slowest < MIN_SAMPLES_PER_DWELL:      # a dwell the solve could not average
        raise plan_table.error("dwell_s", f"{plan.dwell_s:g} s holds fewer than {MIN_SAMPLES_PER_DWELL} IMU samples "
                                          f"at imu.rate_hz = {slowest:g} Hz: must be >= "
                                          f"{MIN_SAMPLES_PER_DWELL / slowest:g} s")
    out = root.table("output", allowed("output"))
    output = OutputConfig(out.path_value("folder", out.string("folder", declared("output", "folder").default,
                                                              nonempty=True)),
                          optional_number(out, "output", "chunk_run_interval_s"))
    sim = _sim(root.table("sim", allowed("sim")), imu.layout.time_stamp is not None)
    acceptance = acceptance_limits(root.table("acceptance", ACCEPTANCE_KEYS))
    chamber = chamber_config(root.table("chamber", CHAMBER_KEYS)) if root.has("chamber") else None
    if plan.thermal is not None:
        check_against_chamber(plan_table, plan.thermal, chamber.limits if chamber is not None else None)
        if not imu.layout.has_column[6]:      # the soak is decided on the IMU's own temperature
            raise plan_table.error("temperatures_c", "a calibration over temperature soaks on the IMU's temperature, "
                                                     "but the IMU signal mapping has no temperature "
                                                     "(imu.signals.temperature)")
    lab = lab_config(root.table("lab", LAB_KEYS))
    terms = model_terms(root.table("model", allowed("model")))
    if units and (plan.thermal is not None or chamber is not None or plan.verification is not None):
        raise root.doc.error(("imu",), "several units ([[imu]]) with a calibration over temperature, a [chamber] or "
                                       "a verification plan are not supported yet")
    run = root.table("run", allowed("run"))
    on_unit_failure = run.string("on_unit_failure", declared("run", "on_unit_failure").default,
                                 choices=declared("run", "on_unit_failure").choices)
    return BenchConfig(site, table, imu, plan, output, sim, source_text=text, acceptance=acceptance, chamber=chamber,
                       lab=lab, units=units, model_terms=terms, on_unit_failure=on_unit_failure)


def load_config(path: str | Path) -> BenchConfig:
    """Load and check a bench configuration file."""
    path = Path(path)
    text = read_text(path, "the configuration file")
    config = parse_config(text, source=str(path), base_dir=path.resolve().parent)
    return dataclasses.replace(config, path=path)


SIM_CONFIG_TOML = f"""\
# The built-in configuration of `bench run --sim` without a file.
format = "{FORMAT}"
version = {VERSION}

[site]
latitude_deg = {HANGZHOU_LATITUDE_DEG}   # Hangzhou, the paper's site
height_m = 0.0

[table]
url = "sim"                 # the simulated table, served over loopback
dialect = "scpi"

[imu]
interface = "virtual"
channel = "turntable-bench-sim"
rate_hz = 200.0

[imu.identity]
model = "simulated FOG IMU"
serial = "SIM-0001"

[plan]
positions = "optimal-24"
rotations = "optimal-5s6r"
dwell_s = 60.0
settle_s = 5.0
turn_rate_dps = 10.0
revolutions = 1

[output]
folder = "runs"

[sim]
seed = 0
black_box_arcsec = 20.0     # RMS of the nine black-box angles
noise = true
"""


def default_sim_config() -> BenchConfig:
    """The configuration `bench run --sim` uses when no file is given (`SIM_CONFIG_TOML`)."""
    return parse_config(SIM_CONFIG_TOML, source="<builtin sim config>")
