"""Load and validate calibration schedules written as TOML.

A schedule file looks like this (angles are (outer, middle, inner) frame angles in
degrees, docs/explanation/model.md#frame-rotations sign convention)::

    format = "turntable-bench/schedule"
    version = 1                 # 1 or 2 (2 adds tilted positions and per-rotation rates, below)
    name = "optimal-24"
    kind = "positions"          # "positions" | "rotations" | "table-check" | "static" | "verification"
    description = "Optimal 24 positions, 12 inner-symmetric groups (paper Table 1)"
    source = "Ma & Zhou 2020, Table 1"   # optional literature reference

    [[position]]                # kinds "positions", "table-check" and "static"
    angles_deg = [0, 0, 0]      # outer, middle, inner
    group = 1                   # optional positive int

    [[rotation]]                # kind "rotations" only
    start_deg = [0, 90, 0]      # outer, middle, inner initial state
    frame = "outer"             # "outer" | "middle" | "inner"
    direction = "ccw"           # "ccw" | "cw"
    revolutions = 1             # whole number, 1..100
    rate_dps = 20.0             # optional, kind "verification" (any version) or "rotations"
                                # (version 2): this turn's rate (default: the plan's turn
                                # rate), 0.001..1000 deg/s

A "verification" schedule (data to check a calibration with, `bench verify`) holds
positions (any angles in [0, 360): tilts of 45 deg) and rotations (with their own rates),
at least one of either.

Version 2 adds two things to the calibration kinds, and nothing else: (a) tilted
positions: a "positions" schedule's angles may be any value in [0, 360) (e.g. 45 deg);
(b) an optional `rate_dps` per `[[rotation]]` in a "rotations" schedule (default: the
plan's turn rate), so one file can hold turns at several rates. Rotation start states
stay multiples of 90 deg, and "static" positions too. A version-1 file keeps exactly its
rules: a tilt or a `rate_dps` in it is refused with a line saying it needs version 2.
A version-2 file is refused by an older bench (it refuses versions it does not know).

Rules checked here (each violation is a one-line `ScheduleError` naming the file,
the 1-based line and the field; the steps are all checked, and the error carries the
file's other problems in `more`):

- top-level keys exactly as above (`source`, `position`, `rotation` optional);
  `format` and `version` must match, `kind` must be known;
- no unknown keys inside a step table (catches typos such as ``angle_deg``), no
  missing required fields, no wrong types (a bool is not a number);
- "static" angles, rotation start states and version-1 "positions" angles are positive
  positions: multiples of 90 in [0, 360); "table-check", "verification" and version-2
  "positions" angles are any finite value in [0, 360);
- `rate_dps` only in "verification" and version-2 "rotations" files;
- a "static" file (one long dwell for noise characterisation) holds exactly one position;
- `group` is a whole number 1..10000, `revolutions` a whole number 1..100;
- no duplicate steps (same angles; same start, frame and direction);
- positions/table-check files hold >= 1 ``[[position]]`` and no ``[[rotation]]``,
  rotations files the reverse; at most 10000 steps;
- the file is a regular file of at most 1 MiB of UTF-8 text, with arrays and inline
  tables nested at most 32 deep (`schedules.tomlinput`).

Steps are numbered from 1 in field names, e.g. ``position[3].angles_deg``.
"""

from __future__ import annotations

import pathlib
import tomllib
from dataclasses import dataclass, replace
from typing import Literal

from schedules.tomlinput import InputLimitError, loads, read_text_file, syntax_error_location
from schedules.tomllines import LineMap, locate_lines

FORMAT = "turntable-bench/schedule"
VERSION = 2                 # the newest version this loader reads
VERSIONS = (1, 2)           # 2: tilted positions and per-rotation rates (module docstring)
KINDS = ("positions", "rotations", "table-check", "static", "verification")
#: a table frame (axis) by name, and a turn's direction (CCW: a positive right-handed rotation about the frame axis)
Frame = Literal["outer", "middle", "inner"]
Direction = Literal["ccw", "cw"]
FRAMES: tuple[Frame, Frame, Frame] = ("outer", "middle", "inner")
DIRECTIONS: tuple[Direction, Direction] = ("ccw", "cw")

_REQUIRED_TOP = ("format", "version", "name", "kind", "description")
_OPTIONAL_TOP = ("source", "position", "rotation")
_POSITION_KEYS = {"angles_deg": True, "group": False}  # key -> required
_ROTATION_KEYS = {"start_deg": True, "frame": True, "direction": True, "revolutions": True}
MAX_STEPS = 10_000        # steps per file (the shipped files have up to 324)
MAX_GROUP = 10_000          # the largest position group number
MAX_REVOLUTIONS = 100     # whole turns per rotation
MIN_RATE_DPS, MAX_RATE_DPS = 1e-3, 1000.0   # a turn's own rate_dps (verification; rotations version 2)


@dataclass(frozen=True)
class PositionStep:
    """One static position: frame angles (outer, middle, inner) in degrees."""

    angles_deg: tuple[float, float, float]
    group: int | None = None
    line: int | None = None  # 1-based line of its [[position]] header


@dataclass(frozen=True)
class RotationStep:
    """One turn: from `start_deg`, `frame` turns `revolutions` whole turns in `direction`."""

    start_deg: tuple[float, float, float]
    frame: Frame
    direction: Direction
    revolutions: int
    line: int | None = None  # 1-based line of its [[rotation]] header
    rate_dps: float | None = None   # its own turn rate (verification; rotations version 2); None: the plan's

    @property
    def sign(self) -> int:
        """+1 for CCW (positive right-handed rotation about the frame axis), -1 for CW."""
        return 1 if self.direction == "ccw" else -1

    @property
    def frame_index(self) -> int:
        """0 outer, 1 middle, 2 inner."""
        return FRAMES.index(self.frame)


@dataclass(frozen=True)
class Schedule:
    """A validated schedule; `source` is where it came from, `reference` its literature source."""

    name: str
    kind: str
    description: str
    source: str
    positions: tuple[PositionStep, ...] = ()
    rotations: tuple[RotationStep, ...] = ()
    reference: str = ""
    version: int = 1              # the file's format version

    @property
    def steps(self) -> tuple[PositionStep | RotationStep, ...]:
        """The positions or the rotations, whichever this kind holds (a verification: both)."""
        if self.kind == "verification":
            return self.positions + self.rotations
        return self.rotations if self.kind == "rotations" else self.positions


class ScheduleError(ValueError):
    """A schedule problem, rendered as one line ``path:line: field: message``.

    `more` holds the file's other problems (the steps are all checked): `str()` names how many
    there are, `lines()` gives one line per problem (`bench schedules validate` prints them all)."""

    def __init__(self, path: str, line: int | None, field: str | None, message: str,
                 more: tuple[ScheduleError, ...] = ()):
        self.path = str(path)
        self.line = line
        self.field = field
        # One line, always: CLI output and logs rely on it.
        self.message = " ".join(str(message).split())
        self.more = tuple(more)
        super().__init__(str(self))

    def __reduce__(self):  # keep it picklable despite the custom __init__
        return type(self), (self.path, self.line, self.field, self.message, self.more)

    def head(self) -> str:
        """This problem alone, as one line."""
        head = self.path if self.line is None else f"{self.path}:{self.line}"
        return ": ".join([head] + ([self.field] if self.field else []) + [self.message])

    def lines(self) -> list[str]:
        """One line per problem of the file, this one first."""
        return [self.head()] + [problem.head() for problem in self.more]

    def __str__(self) -> str:
        if not self.more:
            return self.head()
        n = len(self.more)
        return f"{self.head()} (and {n} more problem{'s' if n > 1 else ''} in this file)"


# --- validation -------------------------------------------------------------------

def _is_number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _show(value: object, limit: int = 60) -> str:
    """`repr(value)` for a message, a long one shortened (a 400-digit number, a 100 kB string)."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10 ** 20:
        digits, sign = str(abs(value)), "-" if value < 0 else ""
        return f"{sign}{digits[0]}.{digits[1:4]}e+{len(digits) - 1} (a {len(digits)}-digit integer)"
    text = repr(value)
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


class _Validator:
    """Turns a parsed TOML document into a `Schedule`. A problem with the file's structure raises
    at once; the steps are all checked, each field on its own, and their problems raised together."""

    def __init__(self, doc: dict, lines: LineMap, path: str):
        self.doc, self.lines, self.path = doc, lines, path
        self.problems: list[ScheduleError] = []
        self.version = 1

    def fail(self, line: int | None, field: str | None, message: str) -> ScheduleError:
        return ScheduleError(self.path, line, field, message)

    def top_string(self, key: str) -> str:
        value = self.doc[key]
        if not isinstance(value, str):
            raise self.fail(self.lines.exact(key), key, f"must be a string, got {_show(value)}")
        return value

    def run(self) -> Schedule:
        doc, lines = self.doc, self.lines
        if "format" not in doc:
            raise self.fail(None, "format", f"missing required key (expected {FORMAT!r})")
        if doc["format"] != FORMAT:
            raise self.fail(lines.exact("format"), "format", f"expected {FORMAT!r}, got {_show(doc['format'])}")
        if "version" not in doc:
            raise self.fail(None, "version", "missing required key")
        if not _is_int(doc["version"]) or doc["version"] not in VERSIONS:
            raise self.fail(lines.exact("version"), "version", f"unsupported version {_show(doc['version'])} "
                            f"(supported: {', '.join(map(str, VERSIONS))})")
        self.version = int(doc["version"])
        for key in doc:
            if key not in _REQUIRED_TOP and key not in _OPTIONAL_TOP:
                allowed = ", ".join(_REQUIRED_TOP + _OPTIONAL_TOP)
                raise self.fail(lines.exact(key), key, f"unknown key (allowed: {allowed})")
        for key in _REQUIRED_TOP:
            if key not in doc:
                raise self.fail(None, key, "missing required key")
        name, kind, description = (self.top_string(k) for k in ("name", "kind", "description"))
        reference = self.top_string("source") if "source" in doc else ""
        if not name.strip():
            raise self.fail(lines.exact("name"), "name", "must not be empty")
        if kind not in KINDS:
            raise self.fail(lines.exact("kind"), "kind",
                            f"unknown kind {_show(kind)} (expected one of {', '.join(KINDS)})")

        if kind == "verification":
            positions, rotations = self._verification()
            self._raise_problems()
            return Schedule(name=name, kind=kind, description=description, source=self.path,
                            positions=positions, rotations=rotations, reference=reference, version=self.version)
        wanted, unwanted = ("rotation", "position") if kind == "rotations" else ("position", "rotation")
        if unwanted in doc:
            raise self.fail(lines.exact(unwanted), unwanted,
                            f"[[{unwanted}]] tables are not allowed in a {kind!r} schedule")
        tables = self._tables(wanted)
        if not tables:
            raise self.fail(None, wanted, f"a {kind!r} schedule needs at least one [[{wanted}]] table")

        if kind == "static" and len(tables) != 1:
            raise self.fail(self.lines.line(wanted, 1), wanted,
                            f"a 'static' schedule holds exactly one [[position]], got {len(tables)}")
        positions, rotations = (), ()
        if kind == "rotations":
            rotations = tuple(self._rotations(tables, with_rate=self.version >= 2, rate_needs_version=True))
        else:
            tilts = kind == "positions" and self.version >= 2
            positive_only = kind == "static" or (kind == "positions" and not tilts)
            positions = tuple(self._positions(tables, positive_only=positive_only,
                                              tilt_needs_version=kind == "positions"))
        self._raise_problems()
        return Schedule(name=name, kind=kind, description=description, source=self.path,
                        positions=positions, rotations=rotations, reference=reference, version=self.version)

    def _raise_problems(self) -> None:
        """The steps' problems, all of them, as one ScheduleError (the first, with the others in `more`)."""
        if self.problems:
            first, *more = self.problems
            raise ScheduleError(first.path, first.line, first.field, first.message, more=tuple(more))

    def _tables(self, wanted: str) -> list:
        tables = self.doc.get(wanted, [])
        if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
            raise self.fail(self.lines.exact(wanted), wanted, f"must be an array of tables ([[{wanted}]])")
        if len(tables) > MAX_STEPS:
            raise self.fail(self.lines.line(wanted, MAX_STEPS), wanted,
                            f"{len(tables)} [[{wanted}]] tables: a schedule holds at most {MAX_STEPS} steps")
        return tables

    def _verification(self) -> tuple[tuple[PositionStep, ...], tuple[RotationStep, ...]]:
        position_tables, rotation_tables = self._tables("position"), self._tables("rotation")
        if not position_tables and not rotation_tables:
            raise self.fail(None, "position", "a 'verification' schedule needs at least one [[position]] or "
                                              "[[rotation]] table")
        if len(position_tables) + len(rotation_tables) > MAX_STEPS:
            raise self.fail(None, "rotation", f"a schedule holds at most {MAX_STEPS} steps")
        return (tuple(self._positions(position_tables, positive_only=False)),
                tuple(self._rotations(rotation_tables, with_rate=True)))

    def _check_keys(self, table_name: str, index: int, table: dict, allowed: dict[str, bool]) -> bool:
        """Note unknown and missing keys; whether every required key is there."""
        label = f"{table_name}[{index + 1}]"
        for key in table:
            if key not in allowed:
                self.problems.append(self.fail(self.lines.line(table_name, index, key), f"{label}.{key}",
                                               f"unknown key (allowed: {', '.join(allowed)})"))
        complete = True
        for key, required in allowed.items():
            if required and key not in table:
                self.problems.append(self.fail(self.lines.line(table_name, index), f"{label}.{key}",
                                               "missing required field"))
                complete = False
        return complete

    def _noted(self, check, *args):
        """`check(*args)`, or None with its ScheduleError noted."""
        try:
            return check(*args)
        except ScheduleError as exc:
            self.problems.append(exc)
            return None

    def _angles(self, table_name: str, index: int, key: str, value: object,
                positive_only: bool, tilt_needs_version: bool = False) -> tuple[float, float, float]:
        line, label = self.lines.line(table_name, index, key), f"{table_name}[{index + 1}].{key}"
        if not isinstance(value, list) or len(value) != 3 or not all(_is_number(v) for v in value):
            raise self.fail(line, label, f"must be 3 numbers [outer, middle, inner] in degrees, got {_show(value)}")
        for axis, angle_deg in zip(FRAMES, value):
            # Compared before any float(): a 400-digit integer compares exactly; NaN fails both tests.
            if not 0 <= angle_deg < 360:
                raise self.fail(line, label, f"{axis} angle {_show(angle_deg)} is outside [0, 360) deg")
            # Exact test on purpose: positive positions are written as whole multiples.
            if positive_only and angle_deg % 90 != 0:
                why = ("a tilted position needs version = 2" if tilt_needs_version
                       else "positive positions only")
                raise self.fail(line, label, f"{axis} angle {angle_deg!r} is not a multiple of 90 deg ({why})")
        outer, middle, inner = (float(v) + 0.0 for v in value)  # + 0.0 turns -0.0 into 0.0
        return outer, middle, inner

    def _positions(self, tables: list[dict], positive_only: bool, tilt_needs_version: bool = False):
        seen: dict[tuple, int] = {}
        for index, table in enumerate(tables):
            if not self._check_keys("position", index, table, _POSITION_KEYS):
                continue
            angles_deg = self._noted(self._angles, "position", index, "angles_deg", table["angles_deg"],
                                     positive_only, tilt_needs_version)
            group = table.get("group")
            if group is not None and (not _is_int(group) or not 1 <= group <= MAX_GROUP):
                self.problems.append(self.fail(self.lines.line("position", index, "group"),
                                               f"position[{index + 1}].group",
                                               f"must be a positive integer in 1..{MAX_GROUP}, got {_show(group)}"))
                continue
            if angles_deg is None:
                continue
            header = self.lines.line("position", index)
            if angles_deg in seen:
                earlier = seen[angles_deg]
                self.problems.append(self.fail(
                    self.lines.line("position", index, "angles_deg"), f"position[{index + 1}].angles_deg",
                    f"duplicate of position[{earlier + 1}] at line {self.lines.line('position', earlier)}"))
                continue
            seen[angles_deg] = index
            yield PositionStep(angles_deg=angles_deg, group=group, line=header)

    def _rotations(self, tables: list[dict], with_rate: bool = False, rate_needs_version: bool = False):
        seen: dict[tuple, int] = {}
        for index, table in enumerate(tables):
            if not with_rate and rate_needs_version and "rate_dps" in table:
                self.problems.append(self.fail(self.lines.line("rotation", index, "rate_dps"),
                                               f"rotation[{index + 1}].rate_dps",
                                               "a per-rotation rate needs version = 2"))
                continue
            if not self._check_keys("rotation", index, table, {**_ROTATION_KEYS, "rate_dps": False} if with_rate
                                    else _ROTATION_KEYS):
                continue
            label = f"rotation[{index + 1}]"
            start_deg = self._noted(self._angles, "rotation", index, "start_deg", table["start_deg"], True)
            valid = start_deg is not None
            for key, choices in (("frame", FRAMES), ("direction", DIRECTIONS)):
                if table[key] not in choices:
                    self.problems.append(self.fail(self.lines.line("rotation", index, key), f"{label}.{key}",
                                                   f"got {_show(table[key])}, expected one of {', '.join(choices)}"))
                    valid = False
            revolutions = table["revolutions"]
            if not _is_int(revolutions) or not 1 <= revolutions <= MAX_REVOLUTIONS:
                self.problems.append(self.fail(
                    self.lines.line("rotation", index, "revolutions"), f"{label}.revolutions",
                    f"must be a whole number in 1..{MAX_REVOLUTIONS}, got {_show(revolutions)}"))
                valid = False
            rate_dps = table.get("rate_dps")
            if rate_dps is not None and (not _is_number(rate_dps) or not MIN_RATE_DPS <= rate_dps <= MAX_RATE_DPS):
                self.problems.append(self.fail(
                    self.lines.line("rotation", index, "rate_dps"), f"{label}.rate_dps",
                    f"must be a number in {MIN_RATE_DPS:g}..{MAX_RATE_DPS:g} deg/s, got {_show(rate_dps)}"))
                valid = False
            if not valid:
                continue
            header = self.lines.line("rotation", index)
            step_key = (start_deg, table["frame"], table["direction"], rate_dps)
            if step_key in seen:
                earlier = seen[step_key]
                self.problems.append(self.fail(header, label, f"duplicate of rotation[{earlier + 1}] at line "
                                               f"{self.lines.line('rotation', earlier)} (same start, frame, "
                                               f"direction{' and rate' if with_rate else ''})"))
                continue
            seen[step_key] = index
            yield RotationStep(start_deg=start_deg, frame=table["frame"], direction=table["direction"],
                               revolutions=revolutions, line=header,
                               rate_dps=None if rate_dps is None else float(rate_dps))


# --- public entry points ----------------------------------------------------------

_BUILTIN_DIR = pathlib.Path(__file__).resolve().parent


def parse_schedule(text: str, path: str = "<string>") -> Schedule:
    """Parse and validate schedule TOML `text`; `path` names it in errors and `Schedule.source`."""
    path = str(path)
    try:
        doc = loads(text)
    except InputLimitError as exc:
        raise ScheduleError(path, exc.line, None, exc.message) from None
    except tomllib.TOMLDecodeError as exc:
        line, message = syntax_error_location(text, exc)
        raise ScheduleError(path, line, None, message) from None
    return _Validator(doc, locate_lines(text), path).run()


def load_schedule(path: str | pathlib.Path) -> Schedule:
    """Load and validate a schedule file."""
    try:
        text = read_text_file(path)  # a regular file of at most 1 MiB
    except UnicodeDecodeError as exc:
        line = exc.object[:exc.start].count(b"\n") + 1
        raise ScheduleError(str(path), line, None, f"cannot read schedule file: not UTF-8 text ({exc.reason} at "
                                                   f"byte {exc.start})") from None
    except (OSError, ValueError) as exc:  # unreadable, beyond the limits, a NUL in the name
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise ScheduleError(str(path), None, None, f"cannot read schedule file: {reason}") from None
    return parse_schedule(text, str(path))


def builtin_names() -> list[str]:
    """Sorted names of the schedules shipped with the package."""
    return sorted(p.stem for p in _BUILTIN_DIR.glob("*.toml"))


def builtin_path(name: str) -> pathlib.Path:
    """Path of a shipped schedule file (unchecked; see `load_builtin`)."""
    return _BUILTIN_DIR / f"{name}.toml"


def load_builtin(name: str) -> Schedule:
    """Load a shipped schedule by name; `Schedule.source` is ``builtin:<name>``."""
    names = builtin_names()
    if name not in names:
        raise ScheduleError(f"builtin:{name}", None, None,
                            f"unknown builtin schedule {name!r} (known: {', '.join(names)})")
    return replace(load_schedule(builtin_path(name)), source=f"builtin:{name}")


def resolve_schedule(name_or_path: str) -> Schedule:
    """A builtin schedule by name, else the schedule file at that path."""
    if name_or_path in builtin_names():
        return load_builtin(name_or_path)
    try:
        exists = pathlib.Path(name_or_path).exists()
    except (OSError, ValueError) as exc:  # a name too long for the file system, a NUL character
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise ScheduleError(_show(name_or_path), None, None, f"cannot read schedule file: {reason}") from None
    if not exists:
        raise ScheduleError(str(name_or_path), None, None,
                            f"no such schedule file or builtin name (builtins: {', '.join(builtin_names())})")
    return load_schedule(name_or_path)
