"""Calibration schedules as data: the shipped TOML files and their loader/validator.

This package imports neither `bench` nor `drivers`; see `schedules.loader` for the
file format.
"""

from schedules.loader import (
    DIRECTIONS,
    FORMAT,
    FRAMES,
    KINDS,
    VERSION,
    PositionStep,
    RotationStep,
    Schedule,
    ScheduleError,
    builtin_names,
    builtin_path,
    load_builtin,
    load_schedule,
    parse_schedule,
    resolve_schedule,
)

__all__ = [
    "DIRECTIONS",
    "FORMAT",
    "FRAMES",
    "KINDS",
    "VERSION",
    "PositionStep",
    "RotationStep",
    "Schedule",
    "ScheduleError",
    "builtin_names",
    "builtin_path",
    "load_builtin",
    "load_schedule",
    "parse_schedule",
    "resolve_schedule",
]
