"""What a run log says about its own run: the configuration, the IMU frame layout, the site and the plan.

The log is the single source of truth, and it may be read on another machine than the
one that recorded it: the configuration's DBC file or schedule files may not exist
here. `layout_and_config_from_log(log)` rebuilds the configuration from the log's
"config" metadata (the TOML text) and takes the files it names from the log's
attachments when they are missing here; the DBC text attached to the log always wins
over a file on disk (the file may have changed since the run). When the configuration
cannot be rebuilt at all, the IMU layout still comes from the attached DBC and the
signal mapping in the recorded TOML, and `LogSetup.notes` says why `config` is None.

`steps_from_log(log)` rebuilds the compiled plan's step records from the "plan"
metadata (`steps_json`, the `bench.plan.steps.step_to_dict` form).

A log of manual moves (`bench tui`: the operator's go-to, rate and jog commands, no plan;
`run.kind` = "manual", `bench.log.run_kind`) has no plan record: `is_manual_log` tells it, and
`steps_from_log` says so in its `LogError` (`NO_PLAN_IN_MANUAL_LOG`).
"""

from __future__ import annotations

import dataclasses
import json
import re
import tempfile
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench.config.load import BenchConfig, ConfigError, parse_config
from bench.log.names import safe_name, shown
from bench.log.reader import LogError, RunLog
from bench.log.run_kind import RunKind, recorded_run_kind
from bench.model.earth import Site
from bench.plan.steps import Step, step_from_dict
from drivers.errors import DeviceConfigError
from drivers.imu import SHIPPED_LAYOUTS, ImuFrameSpec, ImuLayout, shipped_layout_name, spec_of
from schedules import builtin_names
from schedules.tomllines import locate_lines

#: Keys of the configuration that name files the run attaches to its log (by base name).
_ATTACHED_FILE_KEYS = (("imu", "dbc"), ("plan", "positions"), ("plan", "rotations"), ("acceptance", "reference"))
#: The end of the run id of a log of manual moves (`bench tui`).
MANUAL_LOG_SUFFIX = "-manual"
#: Why such a log cannot be solved or resumed.
NO_PLAN_IN_MANUAL_LOG = "a log of manual moves (bench tui), not a calibration run: it holds no calibration plan"
_STRING_LITERAL = re.compile(r'"(?:[^"\\\n]|\\.)*"|\'[^\'\n]*\'')


@dataclass(frozen=True)
class LogSetup:
    """A log's run setup. `config` is None when the recorded configuration cannot be rebuilt here."""

    layout: ImuLayout
    rate_hz: float
    config: BenchConfig | None
    site: Site | None
    notes: tuple[str, ...] = ()    # what was taken from attachments, why config is None
    #: a unit's mounting on the fixture (`C_i^b`, 3x3: a run of several IMUs): its coefficients are solved in its
    #: own body axes; None: the body axes are the fixture's (a single IMU)
    mounting: Any = None
    #: a unit's known place from the table's rotation centre (its body axes, m: `[[imu]] lever_arm_mm`), taken out
    #: of the turns by the extended model's lever-arm fit; None: none known
    lever_arm_m: Any = None


def layout_and_config_from_log(log: RunLog) -> LogSetup:
    """The IMU layout, sample rate, configuration and site of the run that wrote `log`.

    Raises `LogError` when the log holds no way to decode its IMU frames (no
    configuration record and no usable DBC).
    """
    notes: list[str] = []
    text = log.metadata.get("config", {}).get("toml")
    imu_meta = log.metadata.get("imu", {})
    config = None
    if text is not None:
        config = _rebuild_config(log, text, notes)
    if config is not None:
        layout = _prefer_attached_dbc(log, config, notes)
        return LogSetup(layout, float(config.imu.rate_hz), config, config.site.site, tuple(notes))

    # No configuration here: the layout from the attached DBC and the recorded signal mapping.
    spec, shipped_name, dbc_name = _recorded_spec(text, imu_meta, notes)
    layout = _layout_from_attachment(log, dbc_name, spec, shipped_name)
    try:
        rate_hz = float(imu_meta["rate_hz"])
    except (KeyError, ValueError) as exc:
        toml_rate_hz = _toml_rate(text)
        if toml_rate_hz is None:
            raise LogError(f"{log.path}: the log records no IMU sample rate") from exc
        rate_hz = toml_rate_hz
    return LogSetup(layout, rate_hz, None, _site_from_metadata(log, notes), tuple(notes))


def is_manual_log(log: RunLog) -> bool:
    """The log is one of manual moves (`bench tui`), not of a calibration run (such a log has always recorded
    its kind: its metadata tells it, its events are not read)."""
    return recorded_run_kind(log.metadata) is RunKind.MANUAL


def steps_from_log(log: RunLog) -> tuple[Step, ...]:
    """The compiled plan's steps as recorded in the log's "plan" metadata (LogError if absent or malformed)."""
    raw = log.metadata.get("plan", {}).get("steps_json")
    if raw is None and is_manual_log(log):
        raise LogError(f"{log.path}: {NO_PLAN_IN_MANUAL_LOG}")
    if raw is None:
        raise LogError(f"{log.path}: the log has no plan record (plan.steps_json)")
    try:
        rows = json.loads(raw)
        if not isinstance(rows, list):
            raise ValueError("not a list")
        return tuple(step_from_dict(r) for r in rows)
    except (ValueError, TypeError, KeyError) as exc:
        raise LogError(f"{log.path}: the plan record does not hold valid steps ({exc})") from exc


# -- configuration -------------------------------------------------------------------------

def _base_dir(log: RunLog) -> Path:
    path = log.metadata.get("config", {}).get("path", "")
    if path and not path.startswith("<") and "\0" not in path:
        try:
            return Path(path).expanduser().parent
        except RuntimeError:        # "~user/..." of a user unknown here
            pass
    return Path.cwd()


def _rebuild_config(log: RunLog, text: str, notes: list[str]) -> BenchConfig | None:
    source, base_dir = f"{log.path} (recorded configuration)", _base_dir(log)
    try:
        return parse_config(text, source=source, base_dir=base_dir)
    except ConfigError as exc:
        first = str(exc)
    try:
        with tempfile.TemporaryDirectory(prefix="bench-log-") as tmp:
            relocated, moved = _relocate_missing_files(log, text, base_dir, Path(tmp), notes)
            if not moved:
                notes.append(f"configuration not rebuilt: {first}")
                return None
            config = parse_config(relocated, source=source, base_dir=base_dir)
    except ConfigError as exc:
        notes.append(f"configuration not rebuilt: {exc}")
        return None
    notes.append(f"taken from the log's attachments (missing here): {', '.join(moved)}")
    imu = dataclasses.replace(config.imu, dbc=_resolve(base_dir, _toml_value(text, ("imu", "dbc"))) or config.imu.dbc)
    return dataclasses.replace(config, imu=imu, source_text=text)


def _resolve(base_dir: Path, value) -> Path | None:
    if not isinstance(value, str) or not value or "\0" in value:
        return None
    try:
        path = Path(value).expanduser()
    except RuntimeError:            # "~user/..." of a user unknown here
        path = Path(value)
    return path if path.is_absolute() else base_dir / path


def _toml_value(text: str, key_path: tuple[str, ...]):
    try:
        node = tomllib.loads(text)
        for key in key_path:
            node = node[key]
        return node
    except (tomllib.TOMLDecodeError, KeyError, TypeError):
        return None


def _relocate_missing_files(log: RunLog, text: str, base_dir: Path, tmp: Path,
                            notes: list[str]) -> tuple[str, list[str]]:
    """The TOML text with every attached file that is missing here pointed at a copy of its attachment
    (only attachments whose names are safe file names, `bench.log.names.safe_name`)."""

    lines = text.splitlines(keepends=True)
    where = locate_lines(text)
    moved = []
    for key_path in _ATTACHED_FILE_KEYS:
        value = _toml_value(text, key_path)
        path = _resolve(base_dir, value)
        if path is None or path.is_file() or (key_path[0] == "plan" and value in builtin_names()):
            continue
        attached = log.attachments.get(path.name)
        line_no = where.exact(*key_path)
        if attached is None or line_no is None:
            continue
        if safe_name(path.name) is None:        # the name becomes a file name: never "..", a path or a NUL
            notes.append(f"the attachment {shown(path.name)} is not a safe file name: not used")
            continue
        copy = tmp / path.name
        copy.write_bytes(attached[1])
        line = lines[line_no - 1]
        for m in _STRING_LITERAL.finditer(line):
            if _toml_value(f"v = {m.group(0)}", ("v",)) == value:
                lines[line_no - 1] = line[:m.start()] + json.dumps(str(copy)) + line[m.end():]
                moved.append(path.name)
                break
    return "".join(lines), moved


def _prefer_attached_dbc(log: RunLog, config: BenchConfig, notes: list[str]) -> ImuLayout:
    """The configuration's layout, compiled from the log's DBC attachment when that differs from the file here."""
    attached = log.attachments.get(config.imu.dbc.name)
    if attached is None:
        notes.append(f"the log has no {config.imu.dbc.name} attachment: using the DBC file on this machine")
        return config.imu.layout
    text = attached[1].decode("utf-8", errors="replace")
    if text == config.imu.layout.dbc_text:
        return config.imu.layout
    try:
        layout = ImuLayout.from_dbc_string(text, config.imu.spec, source=f"{log.path}:{config.imu.dbc.name}")
    except DeviceConfigError as exc:
        notes.append(f"the attached {config.imu.dbc.name} cannot be used ({exc}): using the file on this machine")
        return config.imu.layout
    notes.append(f"{config.imu.dbc.name} differs from the file on this machine: decoding with the attached copy")
    return layout


def _recorded_spec(text: str | None, imu_meta: dict, notes: list[str]) -> tuple[ImuFrameSpec, str | None, str]:
    """Signal mapping, shipped layout name (None: the IMU's own DBC) and DBC file name from the recorded TOML
    (the classic layout's where absent)."""
    imu = _toml_value(text, ("imu",)) if text is not None else None
    imu = imu if isinstance(imu, dict) else {}
    shipped = shipped_layout_name(imu)
    dbc_value = imu.get("dbc")
    dbc_name = (Path(dbc_value).name if isinstance(dbc_value, str) and dbc_value
                else imu_meta.get("dbc") or SHIPPED_LAYOUTS[shipped or "classic"][0].name)
    fallback = SHIPPED_LAYOUTS[shipped or ("fd" if imu.get("fd") is True else "classic")][1]
    if imu.get("signals") is None:
        return fallback, shipped, dbc_name
    try:
        return spec_of(imu), shipped, dbc_name
    except DeviceConfigError as exc:
        notes.append(f"the recorded [imu.signals] is unusable ({exc}): using the default mapping")
        return fallback, shipped, dbc_name


def _layout_from_attachment(log: RunLog, dbc_name: str, spec: ImuFrameSpec, shipped_name: str | None) -> ImuLayout:
    attached = log.attachments.get(dbc_name)
    if attached is not None:
        try:
            return ImuLayout.from_dbc_string(attached[1].decode("utf-8", errors="replace"), spec,
                                             source=f"{log.path}:{dbc_name}")
        except DeviceConfigError as exc:
            raise LogError(f"{log.path}: the attached DBC {dbc_name} cannot be used: {exc}") from exc
    shipped = SHIPPED_LAYOUTS[shipped_name or "classic"][0]
    if dbc_name == shipped.name:
        try:
            return ImuLayout.from_dbc(shipped, spec)
        except DeviceConfigError as exc:
            raise LogError(f"{log.path}: the shipped {dbc_name} does not fit the recorded mapping: {exc}") from exc
    raise LogError(f"{log.path}: cannot decode the IMU frames: no {dbc_name} attachment and no usable configuration")


def _toml_rate(text: str | None) -> float | None:
    value = _toml_value(text, ("imu", "rate_hz")) if text is not None else None
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) and value > 0 else None


def _site_from_metadata(log: RunLog, notes: list[str]) -> Site | None:
    meta = log.metadata.get("site")
    if not meta:
        notes.append("the log records no site")
        return None

    def number(key):
        value = meta.get(key)
        return None if value in (None, "", "None", "null") else float(value)

    try:
        return Site(number("latitude_deg"), number("height_m") or 0.0, number("local_g"))
    except (TypeError, ValueError) as exc:
        notes.append(f"the recorded site is unusable: {exc}")
        return None


__all__ = ["MANUAL_LOG_SUFFIX", "NO_PLAN_IN_MANUAL_LOG", "LogSetup", "is_manual_log",
           "layout_and_config_from_log", "steps_from_log"]
