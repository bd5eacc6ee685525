"""Every configuration key, declared once: section, name, type, default, range, unit and meaning.

`bench.config.load` takes each section's accepted keys (`allowed`) and each plain number's default and range
(`number`, `integer`, `optional_number`) from `KEYS`; `bench.reference.configuration` renders the table as
docs/reference/configuration.md; tests/unit/config/test_keys.py checks that every key the loader accepts is
here, that the page is current and that bench.example.toml agrees with the defaults and ranges.

A section or a name in angle brackets stands for each member of a set (`PLACEHOLDERS`): `table.limits.<frame>`
is `table.limits.outer`, `table.limits.middle` and `table.limits.inner`.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Any

from bench.acceptance.limits import BEYOND_FAIL, BEYOND_WARN, VERIFICATION_LIMITS
from bench.config.reader import Table
from bench.model.extended import TERMS as EXTENDED_TERMS
from bench.model.families import FAMILY_INFO, canonical_names
from bench.model.higher_order import GRADE_NAMES
from bench.model.imu import NoiseModel
from bench.model.thermal import DIAGONAL_NAMES, THERMAL_NAMES
from bench.plan.thermal import SoakCriterion
from drivers.chamber.base import ABSOLUTE_MAX_C, ABSOLUTE_MIN_C, ChamberLimits
from drivers.turntable import FRAMES, AxisLimits

# Ranges shared by several keys.
MAX_RATE_DPS = 1000.0          # table limits, moves and turns
MIN_RATE_DPS = 1e-3
MAX_ACCEL_DPS2 = 10000.0       # table limits, moves and turns
MIN_ACCEL_DPS2 = 1e-3
MAX_TRAVEL_DEG = 3600.0        # |min_deg|, |max_deg|: ten turns
MAX_BLACK_BOX_ARCSEC = 3600.0  # RMS or each angle: one degree
MAX_CORRELATION_TIME_S = 1e6   # a bias instability's correlation time ([sim.noise], [imu.identity])
#: its lower bound: a bias that decorrelates faster than this is white noise at any IMU rate the bench reads, not
#: a bias instability (and a correlation time of 5e-324 s made the solve's kernel NaN after the whole run)
MIN_CORRELATION_TIME_S = 0.1
MAX_GYRO_STABILITY_DPH = 3600.0       # a data-sheet or measured gyro bias instability
MAX_ACC_STABILITY_UG = 100000.0       # a data-sheet or measured accelerometer bias instability
#: the temperatures a bench can mean, degC (a chamber's range and then some)
MIN_TEMPERATURE_C, MAX_TEMPERATURE_C = -100.0, 200.0
#: the longest thermal time constant of the simulated IMU's case, s
MAX_TIME_CONSTANT_S = 1e6
#: the fastest chamber ramp a configuration may allow, degC/min
MAX_RAMP_C_PER_MIN = 100.0
#: the most chamber temperatures of one plan ([plan] temperatures_c)
MAX_TEMPERATURES = 50
#: the largest [acceptance] max_lost_samples (IMU samples lost on the link)
MAX_LOST_SAMPLES = 10 ** 9
#: the largest [acceptance] max_residual_sigma (|residual| / sigma)
MAX_RESIDUAL_SIGMA = 1e6
#: [acceptance] family -> (lowest, highest, unit) of a value, in result units
VALUE_RANGES = {"Kg": (0.0, 1e9, "counts/s per deg/s"), "Ka": (0.0, 1e9, "counts/s per g"),
                "D0": (-36000.0, 36000.0, "deg/h"), "K0": (-1.0, 1.0, "g"), "Eg": (-1.0, 1.0, ""),
                "Ea": (-1.0, 1.0, "")}
#: [sim.imu] coefficient family -> (lower or None for -upper, upper, unit)
SIM_IMU_RANGES: dict[str, tuple[float | None, float, str]] = {
    "Kg": (0.0, 1e6, "counts/s per deg/s"), "Ka": (0.0, 1e6, "counts/s per g"), "D0": (None, 36000.0, "deg/h"),
    "K0": (None, 1.0, "g"), "Eg": (None, 1.0, ""), "Ea": (None, 1.0, "")}
#: [sim.imu.higher_order] array key -> (meaning, largest |element|, unit, shape text); generous bounds that keep a
#: typo (a value in the wrong unit by 1000) out, far beyond any real IMU
SIM_HIGHER_ORDER_ARRAYS: dict[str, tuple[str, float, str, str]] = {
    "gyro_g_sensitivity_dph_per_g": ("gyro g-sensitivity: rows gyros x y z, columns specific force along body X Y "
                                     "Z", 3600.0, "deg/h per g", "3x3"),
    "gyro_asymmetry_ppm": ("gyro scale-factor asymmetry (K+ - K-) / K per gyro", 1e5, "ppm", "3"),
    "gyro_nonlinearity_ppm_per_dps": ("gyro scale-factor nonlinearity: the error N u^2 of input rate u", 1e3,
                                      "ppm per deg/s", "3"),
    "acc_asymmetry_ppm": ("accelerometer scale-factor asymmetry (K+ - K-) / K per accelerometer", 1e5, "ppm", "3"),
    "acc_second_order_ug_per_g2": ("accelerometer second-order coefficient: the error Q a^2 of input a", 1e5,
                                   "ug/g^2", "3"),
    "acc_cross_ug_per_g2": ("accelerometer cross terms: row s, column j the error C a_s f_j; zero diagonal", 1e5,
                            "ug/g^2", "3x3"),
    "acc_lever_arm_mm": ("each accelerometer's place from the rotation centre: rows x y z, columns body X Y Z "
                         "(size effect)", 1000.0, "mm", "3x3"),
}
#: [sim.imu.higher_order] time_offset_ms: the largest |offset|, ms
MAX_TIME_OFFSET_MS = 100.0

#: what a placeholder in a section or name stands for
PLACEHOLDERS: dict[str, tuple[str, ...]] = {
    "<frame>": tuple(FRAMES),
    "<family>": tuple(FAMILY_INFO),
    "<coefficient>": tuple(canonical_names()),
    "<thermal coefficient>": tuple(THERMAL_NAMES),
    "<diagonal>": tuple(sorted(DIAGONAL_NAMES)),
}


class Default(enum.Enum):
    """A key without a plain default value."""

    REQUIRED = "required"     # the key must be given
    NONE = "none"             # optional; absent means "not given" (the meaning says what follows)


REQUIRED, NONE = Default.REQUIRED, Default.NONE


@dataclass(frozen=True)
class Key:
    """One configuration key. `default` is the value the loader takes when the key is absent (or `REQUIRED`,
    `NONE`); `default_text`, when the default depends on other keys, says how (the loader computes it).
    `gt`, `ge`, `le` bound a number (with both `gt` and `ge` the range is `ge`..`le`; `gt` only words the
    message at or below it); `range_text` words a range that is not one interval."""

    section: str
    name: str
    type: str
    meaning: str
    default: Any = NONE
    unit: str = ""
    gt: float | None = None
    ge: float | None = None
    le: float | None = None
    choices: tuple[str, ...] | None = None
    default_text: str | None = None
    range_text: str | None = None

    @property
    def dotted(self) -> str:
        return f"{self.section}.{self.name}" if self.section else self.name

    def show_default(self) -> str:
        if self.default_text is not None:
            return self.default_text
        if self.default is REQUIRED:
            return "(required)"
        if self.default is NONE:
            return "none"
        if isinstance(self.default, bool):
            return str(self.default).lower()
        if isinstance(self.default, str):
            return f'"{self.default}"'
        if isinstance(self.default, float):
            return f"{self.default:g}"
        return str(self.default)

    def show_range(self) -> str:
        """'0.001..60', '> 0 and <= 86400', '>= 1', one of the choices, or `range_text`."""
        if self.range_text is not None:
            return self.range_text
        if self.choices is not None:
            return ", ".join(f'"{c}"' for c in self.choices)
        if self.ge is not None and self.le is not None:
            return f"{_g(self.ge)}..{_g(self.le)}"
        if self.gt is not None and self.le is not None:
            return f"> {_g(self.gt)} and <= {_g(self.le)}"
        if self.gt is not None:
            return f"> {_g(self.gt)}"
        if self.ge is not None:
            return f">= {_g(self.ge)}"
        if self.le is not None:
            return f"<= {_g(self.le)}"
        return ""


def _g(value: float) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


_AXIS = AxisLimits()
_CHAMBER = ChamberLimits()
_SOAK = SoakCriterion()
_NOISE = NoiseModel()
_SIM_IMU_RANGE = "; ".join(f"{family}: " + (f"> {low:g} and <= {high:g}" if low is not None else
                                              f"-{high:g}..{high:g}") + (f" {unit}" if unit else "")
                           for family, (low, high, unit) in SIM_IMU_RANGES.items())
_ACCEPTANCE_VALUE = "the family's value range: " + "; ".join(
    f"{family} {low:g}..{high:g}" + (f" {unit}" if unit else "") for family, (low, high, unit) in VALUE_RANGES.items())
_VERIFICATION_MEANINGS = {
    "gyro_bias_dph": "largest |gyro bias error|", "gyro_scale_ppm": "largest |gyro scale error| at every rate",
    "gyro_misalignment_arcsec": "largest |gyro misalignment|", "acc_bias_ug": "largest |accelerometer bias error|",
    "acc_scale_ppm": "largest |accelerometer scale error|",
    "acc_misalignment_arcsec": "largest |accelerometer misalignment|",
    "gyro_g_sensitivity_dph_per_g": "largest |gyro g-sensitivity error| (an extended result)",
    "gyro_asymmetry_ppm": "largest |gyro scale-factor asymmetry error| (an extended result)",
    "gyro_nonlinearity_ppm_per_dps": "largest |gyro scale-factor nonlinearity error| (an extended result)"}
_ACCEPTANCE_WIDTH = "> 0 and at most the width of the family's value range"

#: the table, in the order of the documentation (sections as bench.example.toml has them)
KEYS: tuple[Key, ...] = (
    Key("", "format", "string", "always \"turntable-bench/config\"", REQUIRED),
    Key("", "version", "integer", "configuration format version: 1", REQUIRED),
    Key("", "site", "table", "where the turntable stands", REQUIRED),
    Key("", "table", "table", "the turntable controller", REQUIRED),
    Key("", "imu", "table or array of tables", "the IMU under test, read over CAN; or one [[imu]] entry per unit "
        "of several calibrated in one run (docs/how-to/several-imus.md)", REQUIRED),
    Key("", "plan", "table", "what to run", REQUIRED),
    Key("", "model", "table", "the model the solve estimates: the 30 coefficients and any higher-order families"),
    Key("", "output", "table", "where runs are written"),
    Key("", "sim", "table", "the simulated world of `bench run --sim` and of table url \"sim\""),
    Key("", "acceptance", "table", "limits of the result's verdict"),
    Key("", "chamber", "table", "the thermal chamber; without it the bench has no chamber"),
    Key("", "lab", "table", "the calibration lab, the run's customer and item, the equipment used "
        "(docs/how-to/certificates.md)"),
    Key("", "run", "table", "how a run behaves (a run of several IMUs: what a unit that fails does)"),
    # [site]
    Key("site", "latitude_deg", "number", "geodetic latitude, north positive", REQUIRED, "deg", ge=-90.0, le=90.0),
    Key("site", "height_m", "number", "ellipsoidal height", 0.0, "m", ge=-500.0, le=9000.0),
    Key("site", "local_g_mps2", "number", "measured local gravity; absent: WGS84 normal gravity at the latitude "
        "and height", NONE, "m/s^2", ge=9.7, le=9.9),
    Key("site", "latitude_sigma_deg", "number", "1-sigma of latitude_deg, for the uncertainty budget", 0.001, "deg",
        ge=0.0, le=1.0),
    Key("site", "gravity_sigma_mps2", "number", "1-sigma of the gravity used, for the uncertainty budget", 5e-4,
        "m/s^2", ge=0.0, le=0.01, default_text="1e-5 with local_g_mps2, else 5e-4 (the normal formula ignores "
        "anomalies)"),
    # [table]
    Key("table", "url", "string", "where the controller is: tcp://host:port, a serial device, socket://, "
        "modbus+tcp://, modbus+rtu://, visa://, or \"sim\" (the simulated table served over loopback)", REQUIRED),
    Key("table", "dialect", "string", "the controller's protocol (docs/hardware/index.md)", REQUIRED,
        choices=("acutrol", "scpi", "mn", "modbus")),
    Key("table", "timeout_s", "number", "reply timeout per request", 0.5, "s", ge=0.001, le=60.0),
    Key("table", "retries", "integer", "resends after a timeout or garbled reply", 2, ge=0, le=10),
    Key("table", "settle_tolerance_deg", "number", "a move is complete within this of its target", 0.001, "deg",
        ge=1e-6, le=1.0),
    Key("table", "poll_s", "number", "state polling period while moving or settling", 0.05, "s", ge=0.001, le=10.0),
    Key("table", "register_map", "path", "Modbus only: a file holding a [modbus] table (docs/hardware/modbus.md)",
        NONE),
    Key("table", "modbus", "table", "Modbus only: the register map inline (keys as docs/hardware/modbus.md); default: "
        "the documented map", NONE),
    Key("table", "limits", "table", "what the bench may demand of each axis"),
    Key("table", "pointing_accuracy_arcsec", "number or table", "1-sigma (RMS) of each black-box angle, for the "
        "uncertainty budget; or per frame {outer, middle, inner}", NONE, "arcsec", ge=0.0, le=MAX_BLACK_BOX_ARCSEC),
    Key("table.pointing_accuracy_arcsec", "<frame>", "number", "1-sigma of that frame's black-box angles", REQUIRED,
        "arcsec", ge=0.0, le=MAX_BLACK_BOX_ARCSEC),
    Key("table", "orthogonality_arcsec", "number", "1-sigma of the axis tilts (alphas, betas); needs "
        "pointing_accuracy_arcsec, which then covers the gammas", NONE, "arcsec", ge=0.0, le=MAX_BLACK_BOX_ARCSEC),
    Key("table", "check", "path", "a `bench check-table` result (*.table-check.json): its measured combinations "
        "for the budget; the angles it cannot see take pointing_accuracy_arcsec (default 20 arcsec)", NONE),
    Key("table", "turn_angle_error_arcsec", "number", "1-sigma error of each turn's angle (end minus start): "
        "position repeatability at both ends and readback resolution", NONE, "arcsec", ge=0.0,
        le=MAX_BLACK_BOX_ARCSEC, default_text="not included (the report flags it) on hardware, 0 on the simulator"),
    Key("table.limits", "<frame>", "table", "one axis's limits"),
    Key("table.limits.<frame>", "min_deg", "number", "lower travel limit; absent: a continuous axis", NONE, "deg",
        ge=-MAX_TRAVEL_DEG, le=MAX_TRAVEL_DEG),
    Key("table.limits.<frame>", "max_deg", "number", "upper travel limit, above min_deg; absent: a continuous axis",
        NONE, "deg", ge=-MAX_TRAVEL_DEG, le=MAX_TRAVEL_DEG),
    Key("table.limits.<frame>", "max_rate_dps", "number", "rate limit", _AXIS.max_rate_dps, "deg/s",
        ge=MIN_RATE_DPS, le=MAX_RATE_DPS),
    Key("table.limits.<frame>", "max_accel_dps2", "number", "acceleration limit", _AXIS.max_accel_dps2, "deg/s^2",
        ge=MIN_ACCEL_DPS2, le=MAX_ACCEL_DPS2),
            # [imu]
    Key("imu", "interface", "string", "python-can interface: socketcan, pcan, kvaser, vector, virtual, slcan, ...",
        REQUIRED),
    Key("imu", "channel", "string or integer", "python-can channel: \"can0\", \"PCAN_USBBUS1\", 0, ... (a whole "
        "number: 0..65535)", REQUIRED),
    Key("imu", "bitrate", "integer", "nominal bit rate", NONE, "bit/s", ge=1000, le=10_000_000,
        default_text="the interface's own setting"),
    Key("imu", "fd", "boolean", "a CAN FD bus", False),
    Key("imu", "layout", "string", "a shipped frame layout (docs/hardware/can.md); give `dbc` instead for another IMU",
        NONE, choices=("classic", "packed", "fd", "sbg-ecan"), default_text="classic (fd when fd = true)"),
    Key("imu", "dbc", "path", "DBC file of the IMU's frames (a regular file of at most 1 MiB)", NONE,
        default_text="the shipped layout's drivers/imu/sim_imu*.dbc"),
    Key("imu", "rate_hz", "number", "nominal sample rate of the IMU", REQUIRED, "Hz", gt=0.0, ge=1.0, le=100000.0),
    Key("imu", "signals", "table", "which DBC signals carry a sample, as \"MESSAGE.Signal\" (docs/hardware/can.md)",
        NONE, default_text="the shipped layout's mapping"),
    Key("imu", "slcan_client", "string", "who reads an SLCAN adapter (interface = \"slcan\"): the bench's bulk "
        "reader or python-can's own interface", "bench", choices=("bench", "python-can")),
    Key("imu", "bus_options", "table", "extra keyword arguments for python-can's Bus, passed as given (not "
        "interface, channel, bitrate, fd)", NONE),
    Key("imu", "identity", "table", "what is being calibrated (recorded in the log and the result)"),
    Key("imu", "rig", "table", "written by `bench sim rig --write-config`: the rig whose pty and ports the file "
        "names, valid only while it runs; `bench run` refuses the file once that rig has stopped, or when the SLCAN "
        "adapter on the channel is not that rig's", NONE),
    Key("imu", "noise", "path", "a `bench noise` result of this IMU: its largest bias instabilities replace "
        "the identity's data-sheet values in the solve", NONE),
    Key("imu", "mounting", "string or array", "[[imu]] entries only: the unit's mounting on the fixture, a face "
        "(\"z-up\", \"z-down\", \"x-up\", \"x-down\", \"y-up\", \"y-down\": the unit's axis along the fixture's "
        "z) or 3 rows of 3 numbers (the unit's x, y, z axes in fixture coordinates; checked orthonormal, "
        "right-handed)", "z-up"),
    Key("imu", "lever_arm_mm", "array", "[[imu]] entries only: the unit's position from the table's rotation "
        "centre, 3 numbers in the fixture's axes, mm (each finite, within 2000 mm); the simulator places the unit "
        "there and the extended model's solve takes its known specific force out of the turns", NONE),
    Key("imu", "id_offset", "integer", "[[imu]] entries only: added to every frame id of the unit's layout (units "
        "sharing a bus send at distinct ids)", 0, ge=-0x1FFFFFFF, le=0x1FFFFFFF,
        range_text="the layout's ids stay 11-bit (29-bit for extended ids)"),
    Key("imu.signals", "gyro_x", "string", "x gyro increment, counts per sample (gyro_x..acc_z are required "
        "when the table is given)", NONE),
    Key("imu.signals", "gyro_y", "string", "y gyro increment", NONE),
    Key("imu.signals", "gyro_z", "string", "z gyro increment", NONE),
    Key("imu.signals", "acc_x", "string", "x accelerometer increment", NONE),
    Key("imu.signals", "acc_y", "string", "y accelerometer increment", NONE),
    Key("imu.signals", "acc_z", "string", "z accelerometer increment", NONE),
    Key("imu.signals", "temperature", "string", "the IMU's temperature, degC", NONE),
    Key("imu.signals", "status", "string", "the status word", NONE),
    Key("imu.signals", "status_invalid", "integer", "status bits that make a sample unusable (0 = none)", NONE,
        ge=0, le=0xFFFF_FFFF,
        default_text="faults, over-range, initialising (docs/hardware/can.md); 0 with time_stamp"),
    Key("imu.signals", "status_required", "integer", "status bits that must be set in a usable sample (an IMU "
        "whose bits mean \"healthy\")", 0, ge=0, le=0xFFFF_FFFF),
    Key("imu.signals", "counter", "string or table", "sample counter signal in every message, or {message = "
        "signal}", "Counter", default_text="\"Counter\"; none with time_stamp"),
    Key("imu.signals", "crc", "string or table", "CRC-8 signal in every message, or {message = signal}; \"\" = "
        "none", "CRC", default_text="\"CRC\"; none with time_stamp"),
    Key("imu.signals", "time_stamp", "string", "a time stamp signal (unsigned, microseconds) instead of a counter: "
        "its message opens a sample, the channels are then rates and accelerations (sbg-ecan)", NONE),
    Key("imu.rig", "id", "string", "the rig's id, which its simulated SLCAN adapter answers as its serial number",
        REQUIRED),
    Key("imu.rig", "pid", "integer", "the rig's process id", NONE, ge=1),
    Key("imu.rig", "started_utc", "string", "when the rig's process started, ISO 8601 UTC", ""),
    Key("imu.identity", "model", "string", "model name", ""),
    Key("imu.identity", "serial", "string", "serial number", ""),
    Key("imu.identity", "gyro_bias_stability_dph", "number", "data-sheet gyro bias stability", NONE, "deg/h",
        gt=0.0, le=MAX_GYRO_STABILITY_DPH),
    Key("imu.identity", "acc_bias_stability_ug", "number", "data-sheet accelerometer bias stability", NONE, "ug",
        gt=0.0, le=MAX_ACC_STABILITY_UG),
    Key("imu.identity", "bias_correlation_time_s", "number", "correlation time of the bias instability (a "
        "Gauss-Markov bias), for the uncertainty budget and the table check", NONE, "s", gt=0.0,
        ge=MIN_CORRELATION_TIME_S, le=MAX_CORRELATION_TIME_S,
        default_text="the simulated IMU's on the simulator, else 300"),
    Key("imu.identity", "acc_xy_to_z_uncertainty", "number", "1-sigma relative error of the uncalibrated x/y "
        "accelerometers against z: the table check's conversion part without a calibration", NONE, ge=0.0, le=0.1,
        default_text="1e-3"),
    # [model]
    Key("model", "terms", "list of strings", "higher-order families the solve estimates beyond the 30 coefficients "
        "(docs/explanation/extended-model.md): any of " + ", ".join(f"`{t}`" for t in EXTENDED_TERMS)
        + "; or `[\"auto\"]`: those the plan observes and the data find significant; empty: the 30 alone", [],
        default_text="[] (the 30 coefficients)"),
    # [plan]
    Key("plan", "positions", "string", "position schedule: a shipped name (`bench schedules list`) or a file; "
        "\"\" = none (at least one of positions and rotations)", ""),
    Key("plan", "rotations", "string", "rotation schedule, the same", ""),
    Key("plan", "dwell_s", "number", "recording time at each position", 60.0, "s", gt=0.0, le=86400.0),
    Key("plan", "settle_s", "number", "wait after a move is in position before recording", 5.0, "s", ge=0.0,
        le=3600.0),
    Key("plan", "move_rate_dps", "number", "rate of moves between positions (within [table.limits])", 20.0,
        "deg/s", ge=MIN_RATE_DPS, le=MAX_RATE_DPS),
    Key("plan", "move_accel_dps2", "number", "acceleration of moves: the controller's own profile setting, for "
        "the duration estimates", 10.0, "deg/s^2", ge=MIN_ACCEL_DPS2, le=MAX_ACCEL_DPS2),
    Key("plan", "turn_rate_dps", "number", "rate of the calibration turns", 10.0, "deg/s", ge=MIN_RATE_DPS,
        le=MAX_RATE_DPS),
    Key("plan", "turn_accel_dps2", "number", "acceleration of the turns (as move_accel_dps2)", 5.0, "deg/s^2",
        ge=MIN_ACCEL_DPS2, le=MAX_ACCEL_DPS2),
    Key("plan", "rest_s", "number", "recording at rest before and after each turn", 2.0, "s", ge=0.0, le=3600.0),
    Key("plan", "revolutions", "integer", "whole turns per rotation, overriding the schedule's", NONE, ge=1, le=100,
        default_text="as in the schedule"),
    Key("plan", "order", "string", "\"optimal\": least move time; \"listed\": as the schedules list them",
        "optimal", choices=("optimal", "listed")),
    Key("plan", "verification", "string", "a verification schedule run after the calibration on data the fit did "
        "not use", ""),
    Key("plan", "temperatures_c", "array", "a calibration at each chamber temperature, in this order (needs "
        f"[chamber]; each within its limits; at most {MAX_TEMPERATURES})", NONE, "degC",
        range_text=f"each {MIN_TEMPERATURE_C:g}..{MAX_TEMPERATURE_C:g}"),
    Key("plan", "ramp_c_per_min", "number", "the chamber's ramp between temperatures", NONE, "degC/min", gt=0.0,
        le=MAX_RAMP_C_PER_MIN, default_text="the controller's"),
    Key("plan", "soak", "table", "when the IMU has soaked at a temperature"),
    Key("plan.soak", "rate_c_per_min", "number", "the IMU's temperature changes slower than this", _SOAK.rate_c_per_min,
        "degC/min", gt=0.0, le=10.0),
    Key("plan.soak", "stable_min", "number", "for this long", _SOAK.stable_min, "min", gt=0.0, le=1440.0),
    Key("plan.soak", "max_soak_min", "number", "give up waiting after this long (at least stable_min)",
        _SOAK.max_soak_min, "min", gt=0.0, le=10080.0, default_text=f"{_SOAK.max_soak_min:g}, or stable_min if "
        "longer"),
    Key("plan.soak", "chamber_tolerance_c", "number", "the chamber is at its setpoint within this",
        _SOAK.chamber_tolerance_c, "degC", gt=0.0, le=20.0),
    Key("plan.soak", "rate_window_s", "number", "the window the IMU's temperature rate is fitted over (at most "
        "stable_min)", _SOAK.rate_window_s, "s", ge=1.0, le=3600.0,
        default_text=f"{_SOAK.rate_window_s:g}, or stable_min if shorter"),
    # [output]
    Key("output", "folder", "path", "where run logs and results go; relative to the current directory when the "
        "command starts", "runs"),
    Key("output", "chunk_run_interval_s", "number", "the log closes a chunk every this many seconds of run clock "
        "(simulated seconds on the simulator), besides every second of wall time", NONE, "s", gt=0.0, ge=0.01,
        le=3600.0, default_text="5"),
    # [sim]
    Key("sim", "seed", "integer", "random seed of the black-box draw and the sensor noise", 0, ge=0,
        le=2 ** 32 - 1),
    Key("sim", "black_box_arcsec", "number or array", "turntable pointing errors: a number = RMS of the nine "
        "black-box angles drawn with `seed`; or the angles, rows o0, m0, i0 of [alpha, beta, gamma]", 20.0,
        "arcsec", ge=0.0, le=MAX_BLACK_BOX_ARCSEC,
        range_text=f"0..{MAX_BLACK_BOX_ARCSEC:g}; each angle -{MAX_BLACK_BOX_ARCSEC:g}..{MAX_BLACK_BOX_ARCSEC:g}"),
    Key("sim", "noise", "boolean or table", "true = default noise levels, false = noise-free, or the levels", True),
    Key("sim", "imu", "table", "true coefficients of the simulated IMU (any subset; the rest keep the built-in "
        "simulated IMU's values)"),
    Key("sim.noise", "enabled", "boolean", "noise on; false = noise-free (then only quantise may be set)", True),
    Key("sim.noise", "gyro_arw_deg_rt_h", "number", "gyro angle random walk", _NOISE.gyro_arw_deg_rt_h,
        "deg/sqrt(h)", ge=0.0, le=10.0),
    Key("sim.noise", "gyro_bias_instability_dph", "number", "gyro bias instability (1 sigma)",
        _NOISE.gyro_bias_instability_dph, "deg/h", ge=0.0, le=3600.0),
    Key("sim.noise", "acc_vrw_ug_rt_hz", "number", "accelerometer white noise density", _NOISE.acc_vrw_ug_rt_hz,
        "ug/sqrt(Hz)", ge=0.0, le=10000.0),
    Key("sim.noise", "acc_bias_instability_ug", "number", "accelerometer bias instability (1 sigma)",
        _NOISE.acc_bias_instability_ug, "ug", ge=0.0, le=100000.0),
    Key("sim.noise", "correlation_time_s", "number", "bias instability correlation time",
        _NOISE.correlation_time_s, "s", gt=0.0, ge=MIN_CORRELATION_TIME_S, le=MAX_CORRELATION_TIME_S),
    Key("sim.noise", "quantise", "boolean", "integer counts per sample", _NOISE.quantise,
        default_text="true with noise, false without"),
    Key("sim.noise", "gyro_rrw_dph_rt_h", "number", "gyro rate random walk", _NOISE.gyro_rrw_dph_rt_h,
        "deg/h/sqrt(h)", ge=0.0, le=1000.0),
    Key("sim.noise", "acc_rrw_ug_rt_h", "number", "accelerometer bias random walk", _NOISE.acc_rrw_ug_rt_h,
        "ug/sqrt(h)", ge=0.0, le=100000.0),
    Key("sim.imu", "<coefficient>", "number", "a true coefficient by canonical name, display units (direction-"
        "cosine rows are renormalised)", NONE, range_text=_SIM_IMU_RANGE,
        default_text="the built-in simulated IMU's"),
    Key("sim.imu", "thermal", "table", "the simulated IMU's temperature dependence; absent: none, 25 degC"),
    Key("sim.imu", "higher_order", "table", "the simulated IMU's errors beyond the 30 coefficients "
        "(docs/explanation/model.md#higher-order-terms); absent: none"),
    Key("sim.imu.higher_order", "grade", "string", "the preset the other keys start from: none (zero), a "
        "navigation-grade FOG unit or a tactical MEMS unit", "none", choices=GRADE_NAMES),
    *(Key("sim.imu.higher_order", name, "array", meaning, NONE, unit, default_text="the grade's",
          range_text=f"{shape} numbers, each -{high:g}..{high:g}")
      for name, (meaning, high, unit, shape) in SIM_HIGHER_ORDER_ARRAYS.items()),
    Key("sim.imu.higher_order", "time_offset_ms", "number", "the accelerometers' delay behind the gyros", NONE,
        "ms", ge=-MAX_TIME_OFFSET_MS, le=MAX_TIME_OFFSET_MS, default_text="the grade's"),
    Key("sim.imu.thermal", "reference_c", "number", "the [sim.imu] values hold at this case temperature", 25.0,
        "degC", ge=MIN_TEMPERATURE_C, le=MAX_TEMPERATURE_C),
    Key("sim.imu.thermal", "time_constant_s", "number", "the case temperature follows its ambient with this "
        "first-order time constant", 600.0, "s", gt=0.0, le=MAX_TIME_CONSTANT_S),
    Key("sim.imu.thermal", "ambient_c", "number", "the ambient when nothing else drives it (bench run --sim)",
        NONE, "degC", ge=MIN_TEMPERATURE_C, le=MAX_TEMPERATURE_C, default_text="reference_c"),
    Key("sim.imu.thermal", "initial_c", "number", "the case temperature at the start", NONE, "degC",
        ge=MIN_TEMPERATURE_C, le=MAX_TEMPERATURE_C, default_text="the ambient (soaked)"),
    Key("sim.imu.thermal", "<thermal coefficient>", "array", "[c1, c2, c3]: the change per degC, degC^2, degC^3 "
        "from the reference value (not a direction-cosine diagonal)", NONE,
        range_text="1 to 3 terms, each at most the coefficient's range / 100^k"),
    Key("sim.imu.thermal", "<diagonal>", "array", "refused with its reason: a direction-cosine diagonal has no "
        "polynomial, it follows from its row's off-diagonals", NONE, range_text="not allowed"),
    # [acceptance]
    Key("acceptance", "max_lost_samples", "integer", "IMU samples lost on the link", NONE, ge=0,
        le=MAX_LOST_SAMPLES),
    Key("acceptance", "max_residual_sigma", "number", "largest |residual| / sigma of a position or rotation", NONE,
        "sigma", gt=0.0, le=MAX_RESIDUAL_SIGMA),
    Key("acceptance", "reference", "path", "the IMU's nominal or previous result, for max_change", NONE),
    Key("acceptance", "verification", "table", "limits of the errors after compensation on the verification plan",
        NONE),
    Key("acceptance", "<family>", "table", "limits of every coefficient of a family (Kg D0 Eg Ka K0 Ea)", NONE),
    Key("acceptance", "<coefficient>", "table", "limits of one coefficient, overriding its family's key by key",
        NONE),
    *(Key(f"acceptance.<{kind}>", name, "number", meaning, NONE, "result units", range_text=text)
      for kind in ("family", "coefficient")
      for name, meaning, text in (
          ("min", "lowest value (with max)", _ACCEPTANCE_VALUE),
          ("max", "highest value (with min)", _ACCEPTANCE_VALUE),
          ("max_sigma", "largest 1-sigma", _ACCEPTANCE_WIDTH),
          ("max_change", "largest change from nominal or the reference result", _ACCEPTANCE_WIDTH),
          ("nominal", "the nominal value, for max_change", _ACCEPTANCE_VALUE))),
    *(Key("acceptance.verification", name, "number", _VERIFICATION_MEANINGS[name], NONE, unit, gt=0.0, le=high)
      for name, (unit, high) in VERIFICATION_LIMITS.items()),
    Key("acceptance.verification", "beyond_uncertainty", "string", "an error beyond its expanded uncertainty U "
        "fails, or is only marked \"(beyond U)\"", BEYOND_FAIL, choices=(BEYOND_FAIL, BEYOND_WARN)),
    # [chamber]
    Key("chamber", "url", "string", "tcp://host:port, a serial device, modbus+tcp://, modbus+rtu://, or \"sim\" "
        "(the simulated chamber)", REQUIRED),
    Key("chamber", "dialect", "string", "the chamber's protocol", NONE, choices=("ascii", "modbus"),
        default_text="the url's (modbus+...: modbus, else ascii)"),
    Key("chamber", "timeout_s", "number", "reply timeout per attempt", 1.0, "s", ge=0.001, le=60.0),
    Key("chamber", "retries", "integer", "resends after a timeout or garbled reply", 2, ge=0, le=10),
    Key("chamber", "poll_s", "number", "time between state reads", 1.0, "s", ge=0.01, le=600.0),
    Key("chamber", "safe_setpoint_c", "number", "on abort or fault the chamber goes here; absent: it is stopped",
        NONE, "degC", range_text="min_setpoint_c..max_setpoint_c"),
    Key("chamber", "limits", "table", "the chamber's limits, checked before sending"),
    Key("chamber", "register_map", "string", "modbus: \"watlow-f4\", \"generic\", or a file holding a [modbus] "
        "table (docs/hardware/chamber.md)", NONE, default_text="\"watlow-f4\""),
    Key("chamber", "modbus", "table", "modbus: the register map inline (docs/hardware/chamber.md)", NONE),
    Key("chamber.limits", "min_setpoint_c", "number", "lowest setpoint", _CHAMBER.min_setpoint_c, "degC",
        ge=ABSOLUTE_MIN_C, le=ABSOLUTE_MAX_C),
    Key("chamber.limits", "max_setpoint_c", "number", "highest setpoint (above min_setpoint_c)",
        _CHAMBER.max_setpoint_c, "degC", ge=ABSOLUTE_MIN_C, le=ABSOLUTE_MAX_C),
    Key("chamber.limits", "max_ramp_c_per_min", "number", "fastest ramp", _CHAMBER.max_ramp_c_per_min, "degC/min",
        gt=0.0, le=MAX_RAMP_C_PER_MIN),
    # [lab]
    Key("lab", "name", "string", "the calibration lab's name (recorded in the log)", ""),
    Key("lab", "address", "string", "the lab's address", ""),
    Key("lab", "accreditation_id", "string", "the lab's accreditation number; empty: not accredited", ""),
    Key("lab", "country", "string", "the lab's country, ISO 3166-1 alpha-2 (\"CN\", \"DE\"), for the DCC "
        "certificate; empty: \"ZZ\" (unknown) there", ""),
    Key("lab", "email", "string", "the lab's contact e-mail address, on its certificates", ""),
    Key("lab", "certificate_number_pattern", "string", "a certificate's number, with the fields {year}, {run_id} "
        "and {serial} (e.g. \"CAL-{year}-{run_id}\")", ""),
    Key("lab", "equipment", "list of strings", "tags of the registered equipment the run uses (`bench db "
        "equipment add`): checked before anything moves, recorded in the log and the records", NONE,
        default_text="none"),
    Key("lab", "refuse_overdue_equipment", "boolean", "a run with equipment past its calibration due date (or "
        "retired) does not start (exit 2); false: a warning", False),
    Key("lab", "customer", "string", "the run's customer (`bench run --customer` wins)", ""),
    Key("lab", "item", "string", "the item calibrated, as the customer names it (`bench run --item` wins); the "
        "IMU's model and serial are [imu.identity]'s", ""),
    # [run]
    Key("run", "on_unit_failure", "string", "a run of several IMUs ([[imu]]): a unit other than the first that "
        "goes silent or sends only garbage for imu_timeout (2 s) is reported and dropped, the others finish "
        "(\"continue\"), or the run stops safely, the table stopped, exit non-zero (\"stop\")", "continue",
        choices=("continue", "stop")),
)

_BY_NAME: dict[tuple[str, str], Key] = {(key.section, key.name): key for key in KEYS}


def declared(section: str, name: str) -> Key:
    """The declared key `name` of `section` (the section as declared: "table.limits.<frame>"); `name` may be a
    member of a placeholder name ("outer" for "<frame>")."""
    if (section, name) in _BY_NAME:
        return _BY_NAME[section, name]
    for (where, placeholder), entry in _BY_NAME.items():
        if where == section and name in PLACEHOLDERS.get(placeholder, ()):
            return entry
    raise KeyError(f"{section}.{name} is not declared in bench.config.keys.KEYS")


def allowed(section: str) -> tuple[str, ...]:
    """The names a section accepts, placeholders expanded, in the table's order."""
    names: list[str] = []
    for entry in KEYS:
        if entry.section == section:
            names.extend(PLACEHOLDERS.get(entry.name, (entry.name,)))
    return tuple(names)


def match(path: tuple[str, ...]) -> Key | None:
    """The declared key of a concrete dotted path (("table", "limits", "outer", "max_rate_dps")), or None."""
    path = tuple(part for part in path if not isinstance(part, int))    # an [[imu]] entry's index
    for entry in KEYS:
        pattern = tuple(entry.section.split(".")) + (entry.name,) if entry.section else (entry.name,)
        if len(pattern) == len(path) and all(
                part == want or part in PLACEHOLDERS.get(want, ()) for part, want in zip(path, pattern)):
            return entry
    return None


def _number(t: Table, section: str, name: str, default: Any) -> float | None:
    entry = declared(section, name)
    bounds: dict[str, Any] = {"gt": entry.gt, "ge": entry.ge, "le": entry.le, "unit": entry.unit}
    if default is NONE:
        if entry.default is REQUIRED:
            return t.number(name, **bounds)
        default = None if entry.default is NONE else entry.default
    return t.number(name, default, **bounds)


def number(t: Table, section: str, name: str, default: Any = NONE) -> float:
    """`t.number(name, ...)` with the declared default and range (`default`: one computed by the loader); the key
    must have a default or be required."""
    value = _number(t, section, name, default)
    assert value is not None, f"{section}.{name} has no default: use optional_number"
    return value


def optional_number(t: Table, section: str, name: str, default: Any = NONE) -> float | None:
    """`t.number(name, ...)` with the declared range; None when absent and the key has no default."""
    return _number(t, section, name, default)


def integer(t: Table, section: str, name: str) -> int | None:
    """`t.integer(name, ...)` with the declared default and range."""
    entry = declared(section, name)
    low = None if entry.ge is None else int(entry.ge)
    high = None if entry.le is None else int(entry.le)
    if entry.default is REQUIRED:
        return t.integer(name, ge=low, le=high)
    return t.integer(name, None if entry.default is NONE else entry.default, ge=low, le=high)


__all__ = ["KEYS", "NONE", "PLACEHOLDERS", "REQUIRED", "Key", "allowed", "declared", "integer", "match", "number",
           "optional_number"]
