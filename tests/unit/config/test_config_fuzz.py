"""Fuzzing the configuration and schedule readers (issue 13 item 8).

Mutated copies of bench.example.toml and of the shipped schedules (tests/helpers/mutations.py:
lines deleted, duplicated, swapped or uncommented; values replaced with huge, tiny, NaN,
negative and 400-digit numbers, long strings, deep nesting, wrong types and special paths
such as /dev/zero; random bytes; files cut short) either load or raise one `ConfigError` /
`ScheduleError` line naming the file, never anything else. A configuration that loads
compiles to a plan (or a one-line `PlanError`) whose dry run prints; a schedule that loads
prints step by step as `bench schedules show` does.

Deterministic (`derandomize=True`) and bounded (`max_examples`); the command-line fuzzer
(subprocesses, timeouts, peak memory) is fuzz/cli_fuzz.py.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import pytest
from hypothesis import event, given, settings
from hypothesis import strategies as st

from bench.cli.schedules import format_steps
from bench.config.load import ConfigError, load_config
from bench.plan.compiler import PlanError
from bench.run.runner import compile_from_config
from schedules import ScheduleError, builtin_path, load_schedule
from tests.helpers.mutations import mutate

REPO_ROOT = Path(__file__).resolve().parents[3]
EXAMPLE = (REPO_ROOT / "bench.example.toml").read_text(encoding="utf-8")
SCHEDULES = ("optimal-24", "optimal-5s6r", "table-check-324", "traditional-3s6r")
SCHEDULE_TEXTS = {name: builtin_path(name).read_text(encoding="utf-8") for name in SCHEDULES}


def assert_one_line(error: ConfigError | ScheduleError, paths: set[str]) -> None:
    text = str(error)
    assert error.path in paths, text
    assert text.startswith(error.path) and "\n" not in text and "\r" not in text, text
    assert len(text) < 1500 + len(error.path), text


@pytest.mark.slow
@settings(max_examples=150, deadline=None, derandomize=True, database=None)
@given(rnd=st.randoms(use_true_random=False), own_schedule=st.booleans())
def test_mutated_configuration_loads_or_gives_one_config_error(rnd, own_schedule):
    with tempfile.TemporaryDirectory() as folder:
        text, paths = EXAMPLE, {str(Path(folder) / "bench.toml")}
        if own_schedule:  # the plan names a mutated schedule file beside the configuration
            name, key = rnd.choice((("optimal-24", "positions"), ("optimal-5s6r", "rotations")))
            (Path(folder) / "mine.toml").write_bytes(mutate(SCHEDULE_TEXTS[name], rnd))
            text = text.replace(f'{key} = "{name}"', f'{key} = "mine.toml"', 1)
            paths.add(str(Path(folder) / "mine.toml"))
        path = Path(folder) / "bench.toml"
        path.write_bytes(mutate(text, rnd))
        try:
            config = load_config(path)
        except ConfigError as error:
            assert_one_line(error, paths)
            event("ConfigError")  # counts shown by pytest --hypothesis-show-statistics
            return
        try:
            plan = compile_from_config(config)
        except PlanError as error:
            assert "\n" not in str(error), str(error)
            event("PlanError")
            return
        assert "estimated total:" in plan.format_dry_run()
        event("loaded")


@pytest.mark.slow
@settings(max_examples=300, deadline=None, derandomize=True, database=None)
@given(rnd=st.randoms(use_true_random=False), name=st.sampled_from(SCHEDULES))
def test_mutated_schedule_loads_or_gives_one_schedule_error(rnd, name):
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"{name}.toml"
        path.write_bytes(mutate(SCHEDULE_TEXTS[name], rnd))
        try:
            schedule = load_schedule(path)
        except ScheduleError as error:
            assert_one_line(error, {str(path)})
            event("ScheduleError")
            return
        assert len(format_steps(schedule)) == len(schedule.steps) + 1  # a header, a line per step
        event("loaded")
