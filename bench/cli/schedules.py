"""`bench schedules list | show | validate`: inspect and check schedule files."""

from __future__ import annotations

import argparse
import sys

import numpy as np

from bench.cli.common import ExitCode
from bench.cli.recommend import register_recommend
from bench.cli.schedule_tools import register_tools
from bench.model.kinematics import attitude, axis_along, frame_axes_in_body, pointing_labels
from schedules import (
    PositionStep,
    RotationStep,
    Schedule,
    ScheduleError,
    builtin_names,
    load_builtin,
    resolve_schedule,
)

_AXIS_TOL = 1e-6  # a frame axis within this of a unit body axis counts as along it


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `schedules` command and its subcommands to a `bench` CLI parser."""
    parser = subparsers.add_parser(
        "schedules",
        description="Calibration schedules: list the built-in ones, show and validate schedule files, analyze "
                    "their sensitivity to the table's pointing error, search for better ones and recommend "
                    "a plan for a time budget and a table.")
    commands = parser.add_subparsers(dest="schedules_command", metavar="COMMAND", required=True)

    listing = commands.add_parser("list", help="list the built-in schedules")
    listing.set_defaults(func=cmd_list)

    show = commands.add_parser("show", help="print a schedule step by step with body-axis pointing")
    show.add_argument("schedule", metavar="NAME|FILE", help="built-in schedule name or schedule file")
    show.set_defaults(func=cmd_show)

    validate = commands.add_parser("validate", help="check schedule files (or built-in schedules by name)")
    validate.add_argument("files", metavar="NAME|FILE", nargs="+",
                          help="schedule TOML file(s) or built-in schedule name(s)")
    validate.set_defaults(func=cmd_validate)
    register_tools(commands)
    register_recommend(commands)


def cmd_list(args: argparse.Namespace) -> ExitCode:
    """A header row, then one line per built-in schedule: name, kind, step count, description."""
    loaded = [load_builtin(name) for name in builtin_names()]
    name_width = max((len(s.name) for s in loaded), default=4)
    kind_width = max((len(s.kind) for s in loaded), default=4)
    print(f"{'name':<{name_width}}  {'kind':<{kind_width}}  {'steps':>4}  description")
    for schedule in loaded:
        print(f"{schedule.name:<{name_width}}  {schedule.kind:<{kind_width}}  {len(schedule.steps):>4}  "
              f"{schedule.description}")
    return ExitCode.OK


def cmd_show(args: argparse.Namespace) -> ExitCode:
    """Header, then one line per step (pointing on an ideal table, no mounting rotation)."""
    try:
        schedule = resolve_schedule(args.schedule)
    except ScheduleError as exc:
        print(exc, file=sys.stderr)
        return ExitCode.INVALID_SCHEDULE
    for label, value in (("name", schedule.name), ("kind", schedule.kind),
                         ("description", schedule.description), ("source", schedule.source),
                         ("reference", schedule.reference or "-"), ("steps", len(schedule.steps))):
        print(f"{label + ':':<13}{value}")
    print()
    for line in format_steps(schedule):
        print(line)
    return ExitCode.OK


def cmd_validate(args: argparse.Namespace) -> ExitCode:
    """`OK <file>: ...` per valid file, one line per problem on stderr otherwise; 1 if any failed."""
    exit_code = ExitCode.OK
    for path in args.files:
        try:
            schedule = resolve_schedule(path)
        except ScheduleError as exc:
            for line in exc.lines():
                print(line, file=sys.stderr)
            exit_code = ExitCode.INVALID_SCHEDULE
            continue
        print(f"OK {path}: {schedule.name} ({schedule.kind}, {len(schedule.steps)} steps)")
    return exit_code


def _rate(step: RotationStep) -> str:
    """A turn's own rate column: its rate, or the plan's."""
    return f"  {step.rate_dps:g}" if step.rate_dps is not None else "  plan's"


def format_steps(schedule: Schedule) -> list[str]:
    """Table lines (column header first) for the steps of `schedule`."""
    if schedule.kind == "verification":       # both kinds of step; a turn's own rate after it
        lines = ["   #  group  angles (o, m, i) deg  body X Y Z"]
        lines += [_position_line(k, step) for k, step in enumerate(schedule.positions, start=1)]
        lines += ["", "   #  start (o, m, i) deg  body X Y Z  frame   dir  revs  axis  rate deg/s"]
        lines += [_rotation_line(k, step) + _rate(step)
                  for k, step in enumerate(schedule.rotations, start=1)]
    elif schedule.kind == "rotations" and any(step.rate_dps is not None for step in schedule.rotations):
        lines = ["   #  start (o, m, i) deg  body X Y Z  frame   dir  revs  axis  rate deg/s"]    # version 2
        lines += [_rotation_line(k, step) + _rate(step)
                  for k, step in enumerate(schedule.rotations, start=1)]
    elif schedule.kind == "rotations":
        lines = ["   #  start (o, m, i) deg  body X Y Z  frame   dir  revs  axis"]
        lines += [_rotation_line(k, step) for k, step in enumerate(schedule.rotations, start=1)]
    else:
        lines = ["   #  group  angles (o, m, i) deg  body X Y Z"]
        lines += [_position_line(k, step) for k, step in enumerate(schedule.positions, start=1)]
    return lines


def format_angles(angles_deg) -> str:
    """`(  0,  90, 270)`: three right-aligned angles in degrees."""
    return "(" + ", ".join(f"{a:>3g}" for a in angles_deg) + ")"


def pointing(angles_deg) -> str:
    """Where body X, Y, Z point in ENU letters on an ideal table, e.g. 'S U W'."""
    return pointing_labels(attitude(np.radians(angles_deg)))


def turning_axis_label(step: RotationStep) -> str:
    """The body axis the turning frame's axis lies along at the start, e.g. '+X', or '?'."""
    along = axis_along(frame_axes_in_body(np.radians(step.start_deg))[step.frame_index], _AXIS_TOL)
    if along is None:
        return "?"
    k, sign = along
    return ("+" if sign > 0 else "-") + "XYZ"[k]


def _position_line(index: int, step: PositionStep) -> str:
    group = "-" if step.group is None else str(step.group)
    return f"{index:>4}  {group:>5}  {format_angles(step.angles_deg):<20}  {pointing(step.angles_deg)}"


def _rotation_line(index: int, step: RotationStep) -> str:
    return (f"{index:>4}  {format_angles(step.start_deg):<19}  {pointing(step.start_deg):<10}  "
            f"{step.frame:<6}  {step.direction:<3}  {step.revolutions:>4}  {turning_axis_label(step)}")
