"""Schedules: the shipped files, the validator's errors and `bench schedules`."""

from __future__ import annotations

import argparse
import dataclasses
import os
import re
import subprocess
import sys
import textwrap
from collections import Counter
from pathlib import Path

import pytest

import schedules
from bench.cli import schedules as schedules_cli
from schedules import ScheduleError, load_builtin, load_schedule, parse_schedule
from schedules.tomlinput import nesting_error_line

REPO_ROOT = Path(__file__).resolve().parents[3]

# --- shipped schedules --------------------------------------------------------------

EXPECTED_COUNTS = {
    "optimal-24": ("positions", 24),
    "traditional-12": ("positions", 12),
    "all-64": ("positions", 64),
    "optimal-5s6r": ("rotations", 6),
    "traditional-3s6r": ("rotations", 6),
    "all-96": ("rotations", 96),
    "table-check-324": ("table-check", 324),
    "static-noise": ("static", 1),
    "verify-default": ("verification", 34),
    "extended-44": ("positions", 44),
    "extended-5s6r-2rates": ("rotations", 12),
}


def test_builtin_names_are_the_shipped_files():
    assert schedules.builtin_names() == sorted(EXPECTED_COUNTS)


@pytest.mark.parametrize("name", sorted(EXPECTED_COUNTS))
def test_builtin_loads_with_expected_kind_and_count(name):
    schedule = load_builtin(name)
    kind, count = EXPECTED_COUNTS[name]
    assert (schedule.name, schedule.kind, len(schedule.steps)) == (name, kind, count)
    assert schedule.source == f"builtin:{name}"
    assert schedule.reference and schedule.description
    # Every step knows the line of its table header, in file order.
    step_lines = [step.line for step in schedule.steps]
    assert all(step_lines) and step_lines == sorted(step_lines)
    assert schedules.builtin_path(name).read_text(encoding="utf-8").startswith("#")


def test_optimal_24_groups_are_inner_symmetric():
    by_group: dict[int, list[tuple[float, float, float]]] = {}
    for step in load_builtin("optimal-24").positions:
        by_group.setdefault(step.group, []).append(step.angles_deg)
    assert sorted(by_group) == list(range(1, 13))
    for (a, b) in by_group.values():
        assert a[:2] == b[:2]  # same (outer, middle)
        assert abs(a[2] - b[2]) == 180


def test_optimal_24_matches_design_section_3():
    table_1 = [(0, 0, (0, 180)), (0, 90, (90, 270)), (0, 180, (0, 180)), (0, 270, (90, 270)),
               (90, 90, (0, 180)), (90, 270, (0, 180)), (180, 0, (0, 180)), (180, 90, (90, 270)),
               (180, 180, (0, 180)), (180, 270, (90, 270)), (270, 90, (0, 180)), (270, 270, (0, 180))]
    expected = [((o, m, i), g) for g, (o, m, inner) in enumerate(table_1, 1) for i in inner]
    got = [(step.angles_deg, step.group) for step in load_builtin("optimal-24").positions]
    assert got == expected


def test_traditional_12_pairs_each_axis_up_and_down_per_outer_angle():
    steps = load_builtin("traditional-12").positions
    expected = {(o, m, i) for o in (0, 180)
                for (m, i) in ((0, 0), (180, 0), (90, 0), (270, 0), (90, 90), (270, 90))}
    assert {s.angles_deg for s in steps} == expected
    groups: dict[int, list] = {}
    for step in steps:
        groups.setdefault(step.group, []).append(step.angles_deg)
    assert len(groups) == 6
    for a, b in groups.values():
        assert a[0] == b[0] and a[2] == b[2] and abs(a[1] - b[1]) == 180  # same axis flipped


def test_all_64_is_every_multiple_of_90():
    angles = [s.angles_deg for s in load_builtin("all-64").positions]
    assert sorted(angles) == [(o, m, i) for o in range(0, 360, 90)
                              for m in range(0, 360, 90) for i in range(0, 360, 90)]


def test_optimal_5s6r_is_paper_table_3():
    got = [(r.start_deg, r.frame, r.direction, r.revolutions, r.sign, r.frame_index)
           for r in load_builtin("optimal-5s6r").rotations]
    assert got == [((0, 90, 0), "outer", "ccw", 1, 1, 0), ((0, 270, 180), "outer", "cw", 1, -1, 0),
                   ((0, 90, 90), "outer", "ccw", 1, 1, 0), ((0, 270, 270), "outer", "cw", 1, -1, 0),
                   ((0, 0, 0), "inner", "ccw", 1, 1, 2), ((0, 0, 0), "inner", "cw", 1, -1, 2)]


def test_traditional_3s6r_turns_outer_both_ways_from_three_states():
    got = [(r.start_deg, r.frame, r.direction) for r in load_builtin("traditional-3s6r").rotations]
    assert got == [(s, "outer", d) for s in ((0, 90, 0), (0, 90, 90), (0, 0, 0)) for d in ("ccw", "cw")]


def test_all_96_is_48_positive_initial_states_times_two_directions():
    rotations = load_builtin("all-96").rotations
    states = Counter((r.start_deg, r.frame) for r in rotations)
    assert len(states) == 48 and set(states.values()) == {2}
    assert Counter(r.direction for r in rotations) == {"ccw": 48, "cw": 48}
    assert Counter(r.frame for r in rotations) == {"outer": 32, "middle": 32, "inner": 32}
    assert all(r.start_deg[r.frame_index] == 0 and r.revolutions == 1 for r in rotations)


def test_table_check_324_is_outer_major_grid_at_middle_zero():
    angles = [s.angles_deg for s in load_builtin("table-check-324").positions]
    assert angles == [(o, 0, i) for o in range(0, 360, 20) for i in range(0, 360, 20)]


def test_schedules_imports_neither_bench_nor_drivers():
    code = "import sys, schedules; schedules.load_builtin('all-96'); " \
           "print(sorted(m for m in sys.modules if m.split('.')[0] in ('bench', 'drivers')))"
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO_ROOT, capture_output=True,
                         text=True, check=True).stdout
    assert out.strip() == "[]"


def test_steps_are_frozen():
    step = load_builtin("optimal-24").positions[0]
    with pytest.raises(dataclasses.FrozenInstanceError):
        step.group = 3


# --- validation errors ----------------------------------------------------------------

HEAD = 'format = "turntable-bench/schedule"\nversion = 1\nname = "t"\ndescription = "test"\n'
# HEAD is lines 1-4; `kind` goes on line 5, the first step header on line 7.


def _positions_file(body: str, kind: str = "positions") -> str:
    return HEAD + f'kind = "{kind}"\n\n' + textwrap.dedent(body)


ROTATION = '[[rotation]]\nstart_deg = [0, 90, 0]\nframe = "outer"\ndirection = "ccw"\nrevolutions = 1\n'

BAD_FILES = {
    # name: (text, line, field, text in message)
    "missing-field": (HEAD + 'kind = "rotations"\n\n' + ROTATION.replace('direction = "ccw"\n', ""),
                      7, "rotation[1].direction", "missing required field"),
    "angle-45": (_positions_file("""\
        [[position]]
        angles_deg = [0, 0, 0]

        [[position]]
        angles_deg = [0, 45, 0]
        """), 11, "position[2].angles_deg", "middle angle 45 is not a multiple of 90"),
    "unknown-frame": (HEAD + 'kind = "rotations"\n\n' + ROTATION.replace('"outer"', '"outter"'),
                      9, "rotation[1].frame", "'outter'"),
    "duplicate-step": (_positions_file("""\
        [[position]]
        angles_deg = [0, 90, 90]  # S U W
        group = 2

        [[position]]
        angles_deg = [0, 90, 90]
        """), 12, "position[2].angles_deg", "duplicate of position[1] at line 7"),
    "duplicate-rotation": (HEAD + 'kind = "rotations"\n\n' + ROTATION + "\n" + ROTATION.replace("= 1", "= 2"),
                           13, "rotation[2]", "duplicate of rotation[1] at line 7"),
    "revolutions-1.5": (HEAD + 'kind = "rotations"\n\n' + ROTATION.replace("= 1", "= 1.5"),
                        11, "rotation[1].revolutions", "whole number"),
    "typo-angle_deg": (_positions_file("""\
        [[position]]
        angles_deg = [0, 0, 0]

        [[position]]
        # a typo below
        angle_deg = [0, 90, 90]
        """), 12, "position[2].angle_deg", "unknown key"),
    "wrong-format": ('# header\nformat = "turntable-bench/result"\nversion = 1\n', 2, "format",
                     "expected 'turntable-bench/schedule'"),
    "unknown-kind": (_positions_file('[[position]]\nangles_deg = [0, 0, 0]\n', kind="position"),
                     5, "kind", "unknown kind 'position'"),
    "bool-angle": (_positions_file('[[position]]\nangles_deg = [true, 0, 0]\n'),
                   8, "position[1].angles_deg", "3 numbers"),
    "bool-revolutions": (HEAD + 'kind = "rotations"\n\n' + ROTATION.replace("= 1", "= true"),
                         11, "rotation[1].revolutions", "whole number"),
    "group-zero": (_positions_file('[[position]]\nangles_deg = [0, 0, 0]\ngroup = 0\n'),
                   9, "position[1].group", "positive integer"),
    "table-check-360": (_positions_file('[[position]]\nangles_deg = [0, 0, 360]\n', kind="table-check"),
                        8, "position[1].angles_deg", "outside [0, 360)"),
    "rotation-in-positions": (_positions_file('[[position]]\nangles_deg = [0, 0, 0]\n\n' + ROTATION),
                              10, "rotation", "not allowed"),
    "no-steps": (_positions_file("# nothing yet\n"), None, "position", "at least one"),
    "unknown-top-key": (HEAD + 'kind = "positions"\nauthor = "me"\n[[position]]\nangles_deg = [0, 0, 0]\n',
                        6, "author", "unknown key"),
    "version-3": (HEAD.replace("version = 1", "version = 3"), 2, "version", "unsupported version 3 (supported: 1, 2)"),
    # issue 30: a version-1 file keeps its rules; a tilt or a per-rotation rate says it needs version 2
    "v1-tilt": (_positions_file('[[position]]\nangles_deg = [0, 0, 0]\n\n[[position]]\nangles_deg = [90, 45, 0]\n'),
                11, "position[2].angles_deg",
                "middle angle 45 is not a multiple of 90 deg (a tilted position needs version = 2)"),
    "v1-rate": (HEAD + 'kind = "rotations"\n\n' + ROTATION + "\n" + ROTATION.replace("ccw", "cw") + "rate_dps = 40\n",
                18, "rotation[2].rate_dps", "a per-rotation rate needs version = 2"),
    "v2-start-tilted": (HEAD.replace("version = 1", "version = 2") + 'kind = "rotations"\n\n'
                        + ROTATION.replace("[0, 90, 0]", "[0, 45, 0]") + "rate_dps = 40\n",
                        8, "rotation[1].start_deg", "middle angle 45 is not a multiple of 90 deg (positive positions"),
    "v2-static-tilted": (HEAD.replace("version = 1", "version = 2") + 'kind = "static"\n\n'
                         + '[[position]]\nangles_deg = [0, 45, 0]\n', 8, "position[1].angles_deg",
                         "positive positions only"),
    "v2-rate-0": (HEAD.replace("version = 1", "version = 2") + 'kind = "rotations"\n\n' + ROTATION + "rate_dps = 0\n",
                  12, "rotation[1].rate_dps", "must be a number in 0.001..1000 deg/s"),
    "v2-duplicate-rate": (HEAD.replace("version = 1", "version = 2") + 'kind = "rotations"\n\n' + ROTATION
                          + "rate_dps = 10\n\n" + ROTATION + "rate_dps = 10.0\n", 14, "rotation[2]",
                          "duplicate of rotation[1] at line 7 (same start, frame, direction and rate)"),
    "start-not-positive": (HEAD + 'kind = "rotations"\n\n' + ROTATION.replace("[0, 90, 0]", "[0, 90, 30]"),
                           8, "rotation[1].start_deg", "inner angle 30 is not a multiple of 90"),
    # The locator must skip multi-line strings and arrays.
    "multiline-values": (HEAD.replace('description = "test"', 'description = """\n[[position]]\ngroup = 5\n"""')
                         + 'kind = "positions"\n\n[[position]]\nangles_deg = [\n    0,\n    90,\n    0,\n]\n'
                         + "group = -1\n", 16, "position[1].group", "positive integer"),
}


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_bad_file_names_file_line_and_field(tmp_path, case):
    text, line, field, message = BAD_FILES[case]
    path = tmp_path / f"{case}.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ScheduleError) as info:
        load_schedule(path)
    error = info.value
    assert (error.path, error.line, error.field) == (str(path), line, field)
    assert message in error.message
    rendered = str(error)
    assert "\n" not in rendered
    location = f"{path}:{line}: " if line is not None else f"{path}: "
    assert rendered.startswith(location + f"{field}: ")


@pytest.mark.parametrize("text, line", [
    (_positions_file("[[position]\nangles_deg = [0, 0, 0]\n"), 7),   # unclosed header bracket
    (_positions_file("[[position]]\nangles_deg = [0, 0, 0\n"), 8),  # unclosed array at end of file
    # issue 33: an array left open is reported on its own line (tomllib notices it two lines on)
    (_positions_file("[[position]]\nangles_deg = [0, 0, 0  # E N U\n\n[[position]]\nangles_deg = [0, 0, 180]\n"), 8),
])
def test_bad_toml_reports_tomllib_line(tmp_path, text, line):
    path = tmp_path / "broken.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ScheduleError) as info:
        load_schedule(path)
    assert info.value.line == line and info.value.field is None
    assert str(info.value).startswith(f"{path}:{line}: invalid TOML: ")
    assert "\n" not in str(info.value)


def test_missing_file_is_a_schedule_error(tmp_path):
    with pytest.raises(ScheduleError, match="cannot read"):
        load_schedule(tmp_path / "nope.toml")


def test_unknown_builtin_lists_known_names():
    with pytest.raises(ScheduleError) as info:
        load_builtin("optimal-25")
    assert "optimal-24" in str(info.value) and "all-96" in str(info.value)


def test_resolve_schedule_takes_builtin_names_and_paths(tmp_path):
    assert schedules.resolve_schedule("optimal-24").source == "builtin:optimal-24"
    path = tmp_path / "mine.toml"
    path.write_text(_positions_file("[[position]]\nangles_deg = [0, 0, 0]\n"), encoding="utf-8")
    schedule = schedules.resolve_schedule(str(path))
    assert schedule.source == str(path) and schedule.reference == ""
    with pytest.raises(ScheduleError, match="no such schedule"):
        schedules.resolve_schedule(str(tmp_path / "missing.toml"))


def test_parse_schedule_defaults_and_table_check_accepts_any_angle():
    schedule = parse_schedule(_positions_file("[[position]]\nangles_deg = [12.5, 0, 359.9]\n",
                                              kind="table-check"))
    assert schedule.source == "<string>"
    assert schedule.positions == (schedules.PositionStep((12.5, 0.0, 359.9), None, 7),)


def test_version_2_reads_tilts_and_per_rotation_rates():
    """Issue 30: version 2 adds tilted "positions" angles and a `rate_dps` per rotation (default: the plan's)."""
    v2 = HEAD.replace("version = 1", "version = 2")
    positions = parse_schedule(v2 + 'kind = "positions"\n\n[[position]]\nangles_deg = [90, 135, 45]\ngroup = 3\n')
    assert positions.version == 2
    assert positions.positions == (schedules.PositionStep((90.0, 135.0, 45.0), 3, 7),)
    rotations = parse_schedule(v2 + 'kind = "rotations"\n\n' + ROTATION + "rate_dps = 40\n\n" + ROTATION)
    assert [(r.rate_dps, r.line) for r in rotations.rotations] == [(40.0, 7), (None, 14)]
    # the same turn at two rates is two steps, not a duplicate
    two_rates = parse_schedule(v2 + 'kind = "rotations"\n\n' + ROTATION + "rate_dps = 10\n\n" + ROTATION
                               + "rate_dps = 40\n")
    assert [r.rate_dps for r in two_rates.rotations] == [10.0, 40.0]
    # a version-1 file still reads as before
    assert parse_schedule(_positions_file("[[position]]\nangles_deg = [0, 90, 0]\n")).version == 1


def test_version_1_refusals_are_all_listed(tmp_path):
    """Every tilt and every rate of a version-1 file is one located line (`bench schedules validate` prints all)."""
    path = tmp_path / "v1.toml"
    path.write_text(HEAD + 'kind = "rotations"\n\n' + ROTATION + "rate_dps = 10\n\n"
                    + ROTATION.replace("ccw", "cw") + "rate_dps = 40\n", encoding="utf-8")
    with pytest.raises(ScheduleError) as info:
        load_schedule(path)
    assert info.value.lines() == [f"{path}:12: rotation[1].rate_dps: a per-rotation rate needs version = 2",
                                  f"{path}:19: rotation[2].rate_dps: a per-rotation rate needs version = 2"]


def test_schedule_error_omits_missing_parts():
    assert str(ScheduleError("f.toml", None, None, "bad\nthing")) == "f.toml: bad thing"
    assert str(ScheduleError("f.toml", 3, "kind", "x")) == "f.toml:3: kind: x"


# --- CLI ------------------------------------------------------------------------------

# Paper Table 1 pointing column (body X, Y, Z), translated: 东E 西W 南S 北N 天U 地D.
TABLE_1_POINTING = {
    1: ("东北天", "西南天"), 2: ("南天西", "北地西"), 3: ("西北地", "东南地"), 4: ("南地东", "北天东"),
    5: ("天东北", "地西北"), 6: ("地东南", "天西南"), 7: ("西南天", "东北天"), 8: ("北天东", "南地东"),
    9: ("东南地", "西北地"), 10: ("北地西", "南天西"), 11: ("天西南", "地东南"), 12: ("地西北", "天东北"),
}
_CHINESE_TO_ENU = str.maketrans("东西南北天地", "EWSNUD")


def run_cli(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="bench")
    schedules_cli.register(parser.add_subparsers())
    args = parser.parse_args(argv)
    return args.func(args)


def test_cli_list(capsys):
    assert run_cli(["schedules", "list"]) == 0
    header, *lines = capsys.readouterr().out.splitlines()
    assert header.split() == ["name", "kind", "steps", "description"]
    assert len(lines) == len(EXPECTED_COUNTS)
    fields = {line.split()[0]: line.split()[1:3] for line in lines}
    assert fields == {name: [kind, str(count)] for name, (kind, count) in EXPECTED_COUNTS.items()}


def test_cli_show_optimal_24_matches_paper_table_1_pointing(capsys):
    assert run_cli(["schedules", "show", "optimal-24"]) == 0
    out = capsys.readouterr().out
    assert "reference:   Ma & Zhou 2020, Table 1" in out
    step_line = re.compile(r"^\s*(\d+)\s+(\d+)\s+\(\s*(\d+),\s*(\d+),\s*(\d+)\)\s+([ENUWSD?] [ENUWSD?] [ENUWSD?])$")
    rows = [m.groups() for m in map(step_line.match, out.splitlines()) if m]
    assert len(rows) == 24
    got = {int(group): [] for _, group, *_ in rows}
    for _, group, _, _, _, pointing in rows:
        got[int(group)].append(pointing)
    expected = {g: [" ".join(p.translate(_CHINESE_TO_ENU)) for p in pair] for g, pair in TABLE_1_POINTING.items()}
    assert got == expected
    assert re.search(r"^\s*3\s+2\s+\(  0,  90,  90\)\s+S U W$", out, re.M)  # group 2, first position


def test_cli_show_rotations_turning_axis(capsys):
    assert run_cli(["schedules", "show", "optimal-5s6r"]) == 0
    rows = [line.split() for line in capsys.readouterr().out.splitlines() if re.match(r"^\s*\d+\s+\(", line)]
    assert [row[-1][-1] for row in rows] == ["X", "X", "Y", "Y", "Z", "Z"]
    assert [row[-1] for row in rows] == ["+X", "+X", "+Y", "+Y", "+Z", "+Z"]
    assert [row[-4:-1] for row in rows][:2] == [["outer", "ccw", "1"], ["outer", "cw", "1"]]
    assert rows[0][5:8] == ["U", "N", "W"]  # (0, 90, 0): X up


def test_cli_show_table_check_prints_unknown_axes(capsys):
    assert run_cli(["schedules", "show", "table-check-324"]) == 0
    assert re.search(r"\( 20,   0,  20\)\s+\? \? U$", capsys.readouterr().out, re.M)


def test_cli_show_names_the_tilts_and_the_turns_own_rates(capsys):
    """Issue 30: a 45-deg tilt's axes are printed halfway between two directions; a version-2 turn shows its rate."""
    assert run_cli(["schedules", "show", "extended-44"]) == 0
    assert re.search(r"\(  0,  45,   0\)\s+E\+U N W\+U$", capsys.readouterr().out, re.M)
    assert run_cli(["schedules", "show", "extended-5s6r-2rates"]) == 0
    out = capsys.readouterr().out
    assert "rate_dps" in out or "deg/s" in out
    rates = [line.split()[-1] for line in out.splitlines() if re.match(r"\s+\d+\s+\(", line)]
    assert rates == ["10"] * 6 + ["40"] * 6


def test_cli_show_unknown_name_fails(capsys):
    assert run_cli(["schedules", "show", "nothing-like-it"]) == 1
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "optimal-24" in err


def test_cli_validate(tmp_path, capsys):
    good = schedules.builtin_path("optimal-24")
    bad = tmp_path / "bad.toml"
    bad.write_text(BAD_FILES["angle-45"][0], encoding="utf-8")
    assert run_cli(["schedules", "validate", str(good)]) == 0
    assert capsys.readouterr().out == f"OK {good}: optimal-24 (positions, 24 steps)\n"

    assert run_cli(["schedules", "validate", "optimal-24"]) == 0          # a built-in by name, as `show` takes it
    assert capsys.readouterr().out == "OK optimal-24: optimal-24 (positions, 24 steps)\n"

    assert run_cli(["schedules", "validate", str(good), str(bad), str(tmp_path / "missing.toml")]) == 1
    captured = capsys.readouterr()
    assert captured.out.startswith(f"OK {good}:")
    errors = captured.err.splitlines()
    assert len(errors) == 2
    assert errors[0].startswith(f"{bad}:11: position[2].angles_deg: ")
    assert errors[1].startswith(f"{tmp_path / 'missing.toml'}: ")


def test_cli_validate_prints_every_problem_of_a_file(tmp_path, capsys):
    """Not just the first: each bad field of each step is one line (and `str()` says how many more)."""
    bad = tmp_path / "three.toml"
    bad.write_text(HEAD + 'kind = "rotations"\n\n'
                   + ROTATION.replace("[0, 90, 0]", "[0, 90]").replace('"ccw"', '"clockwise"').replace("= 1", "= -1")
                   + "\n" + ROTATION.replace("outer", "inner").replace("wrong_key", "x") + "nonsense = 1\n",
                   encoding="utf-8")
    assert run_cli(["schedules", "validate", str(bad)]) == 1
    errors = capsys.readouterr().err.splitlines()
    assert [line.split(": ")[1] for line in errors] == [
        "rotation[1].start_deg", "rotation[1].direction", "rotation[1].revolutions", "rotation[2].nonsense"]
    assert all(line.startswith(f"{bad}:") for line in errors)
    with pytest.raises(schedules.ScheduleError) as info:
        schedules.load_schedule(bad)
    assert str(info.value) == errors[0] + " (and 3 more problems in this file)"


# --- input limits (issue 13 item 8) -----------------------------------------------------------

DIGITS_400 = "1" + "0" * 399


@pytest.mark.parametrize("text, line, field, fragment", [
    (_positions_file(f"[[position]]\nangles_deg = [0, 0, {DIGITS_400}]\n"), 8, "position[1].angles_deg",
     "inner angle 1.000e+399 (a 400-digit integer) is outside [0, 360) deg"),
    (_positions_file("[[position]]\nangles_deg = [0, nan, 0]\n", kind="table-check"), 8, "position[1].angles_deg",
     "middle angle nan is outside [0, 360)"),
    (_positions_file(f"[[position]]\nangles_deg = [0, 0, 0]\ngroup = {DIGITS_400}\n"), 9, "position[1].group",
     "must be a positive integer in 1..10000, got 1.000e+399 (a 400-digit integer)"),
    (_positions_file("[[position]]\nangles_deg = [0, 0, 0]\ngroup = 10001\n"), 9, "position[1].group", "1..10000"),
    (HEAD + 'kind = "rotations"\n\n' + ROTATION.replace("= 1", f"= {DIGITS_400}"), 11, "rotation[1].revolutions",
     "must be a whole number in 1..100, got 1.000e+399"),
    (HEAD + 'kind = "rotations"\n\n' + ROTATION.replace("= 1", "= 101"), 11, "rotation[1].revolutions",
     "must be a whole number in 1..100, got 101"),
    (HEAD + 'kind = "rotations"\n\n' + ROTATION.replace("= 1", "= 1000000000000"), 11, "rotation[1].revolutions",
     "in 1..100"),
    (_positions_file("[[position]]\nangles_deg = " + "[" * 5000 + "]" * 5000 + "\n"), 8, None,
     "arrays and inline tables nested more than 32 levels deep"),
    (_positions_file("[[position]]\nangles_deg = [0, 0, 0]\nx = " + "{a=" * 3000 + "1" + "}" * 3000 + "\n"), 9, None,
     "nested more than 32 levels deep"),
    (_positions_file("[[position]]\nangles_deg = [0, 0, " + "1" * 5000 + "]\n"), 8, None,
     "an integer with more than 4300 digits"),
    (HEAD + 'kind = "table-check"\nposition = [' + ", ".join(f"{{angles_deg = [0, 0, {i / 100}]}}"
                                                             for i in range(10_001)) + "]\n",
     6, "position", "10001 [[position]] tables: a schedule holds at most 10000 steps"),
    (HEAD.replace('name = "t"', 'name = "t"\nsource = ' + "[" * 20 + "]" * 20) + 'kind = "positions"\n', 4, "source",
     "must be a string, got [[[[[[[[[[[[[[[[[[[[]]]]]]]]]]]]]]]]]]]]"),
    (HEAD.replace("version = 1", f"version = {DIGITS_400}"), 2, "version",
     "unsupported version 1.000e+399 (a 400-digit integer) (supported: 1, 2)"),
], ids=["angle-400-digits", "angle-nan", "group-400-digits", "group-10001", "revolutions-400-digits",
        "revolutions-101", "revolutions-1e12", "deep-array", "deep-inline-table", "5000-digits", "10001-steps",
        "deep-source", "version-400-digits"])
def test_out_of_range_and_oversized_values_give_one_located_line(tmp_path, text, line, field, fragment):
    path = tmp_path / "s.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ScheduleError) as info:
        load_schedule(path)
    error = info.value
    assert (error.path, error.line, error.field) == (str(path), line, field), str(error)
    assert fragment in error.message and "\n" not in str(error), str(error)
    assert len(str(error)) < 400, str(error)


def test_limits_hold_at_their_edges():
    rotations = parse_schedule(HEAD + 'kind = "rotations"\n\n' + ROTATION.replace("= 1", "= 100"))
    assert rotations.rotations[0].revolutions == 100
    positions = parse_schedule(_positions_file("[[position]]\nangles_deg = [0, 0, 270]\ngroup = 10000\n"))
    assert positions.positions[0].group == 10000
    many = HEAD + 'kind = "table-check"\nposition = [' + ", ".join(f"{{angles_deg = [0, 0, {i / 100}]}}"
                                                                 for i in range(10_000)) + "]\n"
    assert len(parse_schedule(many).positions) == 10_000


def test_only_small_regular_files_are_read(tmp_path):
    """/dev/zero would fill the memory, a FIFO without a writer would block: neither is read."""
    for special, fragment in (("/dev/zero", "not a regular file (a character device)"),
                              (str(tmp_path), "Is a directory")):
        with pytest.raises(ScheduleError) as info:
            load_schedule(special)
        assert str(info.value) == f"{special}: cannot read schedule file: {fragment}"
    fifo = tmp_path / "fifo.toml"
    os.mkfifo(fifo)
    with pytest.raises(ScheduleError, match=r"not a regular file \(a FIFO\)"):
        load_schedule(fifo)
    big = tmp_path / "big.toml"
    good = schedules.builtin_path("optimal-24").read_text(encoding="utf-8")
    big.write_text(good + "#" * (1024 * 1024 - len(good)), encoding="utf-8")  # exactly 1 MiB: read
    assert load_schedule(big).name == "optimal-24"
    with big.open("a", encoding="utf-8") as f:
        f.write("\n")
    with pytest.raises(ScheduleError) as info:
        load_schedule(big)
    assert str(info.value) == f"{big}: cannot read schedule file: larger than the 1 MiB limit for input files"


@pytest.mark.parametrize("name, fragment", [("a\0b.toml", "no such schedule file|embedded null byte"),
                                            ("p" * 5000, "File name too long")], ids=["nul", "long"])
def test_unusable_schedule_names_are_schedule_errors(name, fragment):
    with pytest.raises(ScheduleError, match=fragment) as info:
        schedules.resolve_schedule(name)
    assert "\n" not in str(info.value) and len(str(info.value)) < 300
    with pytest.raises(ScheduleError, match=fragment):
        load_schedule(name)


def test_nesting_check_skips_strings_and_comments():
    deep = "[" * 40
    text = (f'# {deep}\na = "{deep} \\" {deep}"\nb = \'{deep}\'\nc = """\n{deep}\\"""\n{deep}"""\n'
            f"d = '''{deep}\n'''\ne = [[1], {{ f = [2] }}]  # {deep}\n")
    assert nesting_error_line(text) is None
    assert nesting_error_line(text + "g = " + "[" * 33 + "]" * 33 + "\n") == 10
    assert nesting_error_line("h = " + "[" * 32 + "]" * 32) is None


def test_a_file_that_is_not_utf8_names_the_line(tmp_path):
    path = tmp_path / "latin1.toml"
    text = _positions_file("[[position]]\nangles_deg = [0, 0, 0]  # caf\xe9\n")
    path.write_bytes(text.encode("latin-1"))
    at = text.index("\xe9")
    with pytest.raises(ScheduleError) as info:
        load_schedule(path)
    assert str(info.value) == (f"{path}:8: cannot read schedule file: not UTF-8 text (invalid continuation byte "
                               f"at byte {at})")
