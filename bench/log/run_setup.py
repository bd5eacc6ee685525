"""What must agree between the logs of one run, and between a log and the run that resumes it.

Units are merged by label (`P03`, `R02`): that is only right when every log is of the same
plan, IMU, site and table. `RunSetup` is that setup, read from a log's metadata
(`setup_of_log`) or from the configuration and compiled plan of a run about to start
(`setup_of_run`); `differences(a, b)` names what differs, one short phrase each:

- the mode (simulator or hardware) and, on the simulator, the simulated world ([sim]);
- the IMU: model and serial (identity), sample rate, the DBC its frames are decoded with;
- the site (latitude, height, local g) and the table (url and dialect);
- the plan: the schedules by name and by content (every observation unit's nominal
  position or turn), the timing (dwell, settle, move and turn rates, turn acceleration,
  rest, revolutions) and the order (the `order` setting and the visiting order of the units).

`bench run --resume` (`bench.run.resume`) and `bench solve` with several logs
(`bench.finish.recorded.load_recorded`) refuse logs that differ.
"""

from __future__ import annotations

import dataclasses
import json
import tomllib
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from bench.errors import InputError
from bench.log.names import shown
from bench.log.reader import LogError, RunLog
from bench.log.run_info import layout_and_config_from_log, steps_from_log
from bench.plan.steps import step_to_dict

if TYPE_CHECKING:
    from bench.config.load import BenchConfig, SimConfig
    from bench.plan.compiler import CompiledPlan

#: Timing fields of the step records: (step kind, field, what it is called in a message, unit).
_TIMING = (("dwell", "dwell_s", "dwell", "s"), ("settle", "duration_s", "settle", "s"),
           ("move", "rate_dps", "move rate", "deg/s"), ("turn", "rate_dps", "turn rate", "deg/s"),
           ("turn", "accel_dps2", "turn acceleration", "deg/s^2"), ("turn", "rest_s", "turn rest", "s"),
           ("turn", "revolutions", "revolutions", ""))


class SetupMismatch(InputError):
    """Logs (or a log and a run) of different plans, IMUs, sites or tables."""


@dataclass(frozen=True)
class RunSetup:
    """The setup of one run, as far as merging its logs by unit label depends on it."""

    mode: str                                   # "simulator" | "hardware" | "" (not recorded)
    imu: tuple[str, str]                        # model, serial
    rate_hz: float | None
    dbc: tuple[str, str | None]                 # file name, its text (None: not recorded)
    site: tuple[float | None, float | None, float | None]   # latitude deg, height m, local g m/s^2
    table: tuple[str, str]                      # url, dialect ("" when not recorded)
    sim_world: str | None                       # the simulated world (simulator only), canonical JSON
    positions: str                              # schedule names ("" = none)
    rotations: str
    order: str
    steps: tuple[dict, ...] | None              # every step as `step_to_dict`; None: no usable plan record


# -- building ------------------------------------------------------------------------------------

def setup_of_run(config: BenchConfig, plan: CompiledPlan, *, sim: bool) -> RunSetup:
    """The setup a run of `plan` with `config` will record (what `bench.run.runner.BenchRun` writes)."""
    identity = config.imu.identity
    return RunSetup(
        mode="simulator" if sim else "hardware", imu=(identity.model, identity.serial),
        rate_hz=float(config.imu.rate_hz), dbc=(config.imu.dbc.name, config.imu.layout.dbc_text),
        site=_site(config.site.site.to_dict()), table=(config.table.url.strip(), config.table.dialect.strip().lower()),
        sim_world=_sim_world(config.sim) if sim else None,
        positions=config.plan.positions.name if config.plan.positions is not None else "",
        rotations=config.plan.rotations.name if config.plan.rotations is not None else "",
        order=plan.order, steps=tuple(step_to_dict(s) for s in plan.steps))


def setup_of_log(log: RunLog) -> RunSetup:
    """The setup `log` records (missing parts are empty or None, and differ from a recorded one)."""
    meta = log.metadata
    run, imu, plan = meta.get("run") or {}, meta.get("imu") or {}, meta.get("plan") or {}
    try:
        rate_hz: float | None = float(imu["rate_hz"])
    except (KeyError, TypeError, ValueError):
        rate_hz = None
    dbc_name = str(imu.get("dbc", ""))
    attached = log.attachments.get(dbc_name)
    toml_text = (meta.get("config") or {}).get("toml")
    raw = _toml(toml_text)
    table = raw.get("table")
    table = table if isinstance(table, dict) else {}
    mode = str(run.get("mode", ""))
    try:
        steps: tuple[dict, ...] | None = tuple(step_to_dict(s) for s in steps_from_log(log))
    except LogError:
        steps = None
    return RunSetup(
        mode=mode, imu=(str(imu.get("model", "")), str(imu.get("serial", ""))), rate_hz=rate_hz,
        dbc=(dbc_name, attached[1].decode("utf-8", errors="replace") if attached is not None else None),
        site=_site(meta.get("site") or {}),
        table=(str(table.get("url", "")).strip(), str(table.get("dialect", "")).strip().lower()),
        sim_world=_log_sim_world(log, raw) if mode == "simulator" else None,
        positions=str(plan.get("positions", "")), rotations=str(plan.get("rotations", "")),
        order=str(plan.get("order", "")), steps=steps)


def _toml(text: object) -> dict:
    if not isinstance(text, str):
        return {}
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError:
        return {}


def _number(value: object) -> float | None:
    if value in (None, "", "None", "null"):
        return None
    try:
        return float(value)   # type: ignore[arg-type]  # str or number; anything else is caught
    except (TypeError, ValueError):
        return None


def _site(values: dict) -> tuple[float | None, float | None, float | None]:
    return _number(values.get("latitude_deg")), _number(values.get("height_m")), _number(values.get("local_g"))


def _sim_world(sim: SimConfig) -> str:
    imu = {f.name: getattr(sim.imu, f.name).tolist() for f in dataclasses.fields(sim.imu)}
    return json.dumps({"seed": sim.seed, "black_box_rad": sim.black_box_rad.tolist(),
                       "noise": dataclasses.asdict(sim.noise), "imu": imu}, sort_keys=True)


def _log_sim_world(log: RunLog, raw: dict) -> str:
    """The simulated world of a simulator log: from its rebuilt configuration, else its [sim] table as written."""
    try:
        config = layout_and_config_from_log(log).config
    except LogError:
        config = None
    if config is not None:
        return _sim_world(config.sim)
    return json.dumps({"sim (as written)": raw.get("sim")}, sort_keys=True, default=str)


# -- comparing -----------------------------------------------------------------------------------

def differences(a: RunSetup, b: RunSetup, a_name: str = "the log", b_name: str = "this run") -> list[str]:
    """What differs between two setups, one short phrase each (empty: they agree)."""
    out: list[str] = []

    def differ(what: str, x: Any, y: Any) -> None:
        out.append(f"{what} {x} in {a_name}, {y} in {b_name}")

    if a.mode != b.mode:
        differ("mode", shown(a.mode), shown(b.mode))
    if a.imu != b.imu:
        differ("IMU", _imu(a.imu), _imu(b.imu))
    if a.rate_hz != b.rate_hz:
        differ("IMU rate", f"{a.rate_hz} Hz", f"{b.rate_hz} Hz")
    if a.dbc != b.dbc:
        what = "the IMU DBC differs" if a.dbc[1] is not None and b.dbc[1] is not None else "the IMU DBC"
        differ(what, _dbc(a.dbc), _dbc(b.dbc))
    if a.site != b.site:
        differ("site", _site_text(a.site), _site_text(b.site))
    if a.table != b.table:
        differ("table", f"{shown(a.table[0])} ({shown(a.table[1])})", f"{shown(b.table[0])} ({shown(b.table[1])})")
    if a.sim_world != b.sim_world:
        out.append(f"the simulated world ([sim]: seed, black box, noise, true IMU) differs between {a_name} and "
                   f"{b_name}")
    if a.positions != b.positions:
        differ("position schedule", shown(a.positions), shown(b.positions))
    if a.rotations != b.rotations:
        differ("rotation schedule", shown(a.rotations), shown(b.rotations))
    if a.order != b.order:
        differ("plan order", shown(a.order), shown(b.order))
    if a.steps is None or b.steps is None:
        if a.steps is not b.steps:
            missing = a_name if a.steps is None else b_name
            out.append(f"{missing} records no usable plan (plan.steps_json): the plans cannot be compared")
        return out
    if (a.positions, a.rotations) == (b.positions, b.rotations):
        out += _content(a.steps, b.steps, a_name, b_name)
    for kind, key, what, unit in _TIMING:
        x, y = _values(a.steps, kind, key), _values(b.steps, kind, key)
        if x and y and x != y:
            differ(what, _fmt(x, unit), _fmt(y, unit))
    if not out and _visits(a.steps) != _visits(b.steps):
        out.append(f"the units are visited in another order in {a_name} than in {b_name}")
    return out


def nominal(step: dict) -> tuple:
    """An observation step's nominal identity: its schedule entry and position or turn (not the timing)."""
    if step.get("kind") == "dwell":
        return ("dwell", step.get("schedule"), step.get("schedule_index"), _angles(step.get("angles_deg")))
    return ("turn", step.get("schedule"), step.get("schedule_index"), _angles(step.get("start_deg")),
            step.get("frame"), step.get("direction"))


def _angles(values: object) -> tuple:
    if not isinstance(values, (list, tuple)):
        return (shown(values),)
    try:
        return tuple(round(float(v) % 360.0, 6) % 360.0 for v in values)
    except (TypeError, ValueError):
        return (shown(values),)


def _observations(steps: tuple[dict, ...]) -> dict[str, tuple]:
    return {str(s.get("unit")): nominal(s) for s in steps if s.get("kind") in ("dwell", "turn")}


def _content(a: tuple[dict, ...], b: tuple[dict, ...], a_name: str, b_name: str) -> list[str]:
    x, y = _observations(a), _observations(b)
    if x == y:
        return []
    only_a, only_b = sorted(set(x) - set(y)), sorted(set(y) - set(x))
    if only_a or only_b:
        return [f"the schedules' units differ ({_units(only_a)} only in {a_name}, {_units(only_b)} only in {b_name})"]
    unit = next(u for u in sorted(x) if x[u] != y[u])
    return [f"schedule content differs: unit {shown(unit)} is {_describe(x[unit])} in {a_name}, "
            f"{_describe(y[unit])} in {b_name}"]


def _units(units: list[str]) -> str:
    if not units:
        return "none"
    return ", ".join(map(shown, units[:4])) + (f" and {len(units) - 4} more" if len(units) > 4 else "")


def _describe(key: tuple) -> str:
    angles = "(" + ", ".join(f"{a:g}" if isinstance(a, float) else str(a) for a in key[3]) + ")"
    return f"{angles}" if key[0] == "dwell" else f"{angles} {key[4]} {key[5]}"


def _values(steps: tuple[dict, ...], kind: str, key: str) -> tuple:
    return tuple(sorted({json.dumps(s.get(key)) for s in steps if s.get("kind") == kind}))


def _fmt(values: tuple, unit: str) -> str:
    return ", ".join(shown(json.loads(v)) if not _is_number(v) else v for v in values) + (f" {unit}" if unit else "")


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _visits(steps: tuple[dict, ...]) -> list[str]:
    return [str(s.get("unit")) for s in steps if s.get("kind") in ("dwell", "turn")]


def _imu(imu: tuple[str, str]) -> str:
    return f"{shown(imu[0])} serial {shown(imu[1])}"


def _dbc(dbc: tuple[str, str | None]) -> str:
    return shown(dbc[0]) + (" (not attached)" if dbc[1] is None else "")


def _site_text(site: tuple) -> str:
    lat, height, g = site
    return f"latitude {lat} deg, height {height} m, local g {g}"


def check_same_setup(a: RunSetup, b: RunSetup, a_name: str, b_name: str, what: str) -> None:
    """Raise `SetupMismatch` ("`what`: difference; difference") unless the setups agree."""
    found = differences(a, b, a_name, b_name)
    if found:
        raise SetupMismatch(f"{what}: " + "; ".join(found))


__all__ = ["RunSetup", "SetupMismatch", "check_same_setup", "differences", "nominal", "setup_of_log",
           "setup_of_run"]
