"""Duration estimates model what the run takes, and the plan stays the same whoever runs it (issue 33 item 16).

The printed estimates (`bench run --dry-run`, `bench check-table`'s line, the progress) were [plan]'s: a real
controller's accelerations and command latency, and a soak as the air's change at 2 degC/min plus the stable
time. The simulator moves at its table's limits and its IMU lags the air: the table check's estimate was 28 % long,
the thermal run's 15-22 % short. The plan itself (its steps, their commanded values, what the log records) must
not depend on who runs it: `bench run --resume` compares the plan with the log's.
"""

from __future__ import annotations

import io
import json
import re

import pytest

from bench.config.load import parse_config
from bench.log.events import StepFinished, StepStarted
from bench.log.reader import read_log
from bench.plan.retime import SoakModel, TimingProfile, retime
from bench.plan.steps import SetTemperatureStep, SoakStep, step_to_dict
from bench.run.runner import compile_from_config
from bench.run.timing import timing_profile
from tests.helpers.run import cli, config_text, thermal_config_text


def _hms(text: str) -> float:
    h, m, s = (int(x) for x in text.split(":"))
    return 3600.0 * h + 60.0 * m + s


def _dry_run_total_s(argv: list[str]) -> float:
    rc, out, err = cli(["run", "--dry-run", *argv])
    assert rc == 0, err
    line = next(s for s in out.splitlines() if s.startswith("estimated total:"))
    return float(re.search(r"\((\d+\.\d) s\)", line).group(1))


def _simulated_s(log_path) -> float:
    events = read_log(log_path).events
    return events[-1].time_s - events[0].time_s


# -- the estimate is what the simulated run takes ------------------------------------------------------------------

def test_the_dry_run_estimate_of_a_simulated_run_is_its_simulated_duration(noisy_run):
    # 2 s dwells: the moves weigh; [plan]'s 10 deg/s^2 and 0.5 s a move made the estimate 6 % long
    estimated = _dry_run_total_s(["--config", str(noisy_run.config), "--sim"])
    assert estimated == pytest.approx(_simulated_s(noisy_run.log), rel=0.01)


def test_the_dry_run_estimate_of_a_thermal_run_counts_the_imus_own_settling(thermal_run_log):
    # the soaks last until the IMU (60 s time constant) is steady, after the simulated air (240 s) arrives: the
    # estimate counted the air at 2 degC/min plus the stable time and was 22 % short (560 s for 719 s)
    estimated = _dry_run_total_s(["--config", str(thermal_run_log.parent / "bench.toml"), "--sim"])
    assert estimated == pytest.approx(_simulated_s(thermal_run_log), rel=0.03)


def test_each_soaks_estimate_is_its_simulated_soak(thermal_run_log):
    config = parse_config((thermal_run_log.parent / "bench.toml").read_text(encoding="utf-8"))
    plan = compile_from_config(config)
    estimates = retime(plan.steps, timing_profile(config, sim=True))
    events = read_log(thermal_run_log).events
    started = {e.step_index: e.time_s for e in events if isinstance(e, StepStarted)}
    took = {e.step_index: e.time_s - started[e.step_index] for e in events if isinstance(e, StepFinished)}
    soaks = [s.index for s in plan.steps if isinstance(s, SoakStep)]
    assert len(soaks) == 2
    for k in soaks:
        # the simulated chamber's reading (0.1 degC) meets the tolerance some seconds before the true air does
        assert estimates[k] == pytest.approx(took[k], rel=0.06, abs=5.0)


@pytest.mark.slow      # a 16-position table check on the simulator: a few seconds
def test_a_simulated_table_checks_printed_estimate_is_its_simulated_duration(tmp_path):
    # 0:50:19 printed for 0:39:16 simulated (324 positions, 1 s dwells): moves at 10 deg/s^2 plus 0.5 s each
    lines = ['format = "turntable-bench/schedule"', "version = 1", 'name = "table-check-16"', 'kind = "table-check"',
             'description = "short table check for tests"', ""]
    lines += [f"[[position]]\nangles_deg = [{o}, 0, {i}]\n" for o in (0, 90, 180, 270) for i in (45, 135, 225, 315)]
    schedule = tmp_path / "table-check-16.toml"
    schedule.write_text("\n".join(lines), encoding="utf-8")
    rc, out, err = cli(["check-table", "--sim", "--schedule", str(schedule), "--dwell-s", "1", "--out",
                        str(tmp_path / "out"), "--no-db"])
    assert rc == 0, err
    said = out + err
    estimated = _hms(re.search(r"about (\d+:\d\d:\d\d) of table time", said).group(1))
    simulated = _hms(re.search(r"steps done in (\d+:\d\d:\d\d) simulated", said).group(1))
    assert estimated == pytest.approx(simulated, rel=0.03, abs=2.0)


# -- the plan is the same whoever runs it --------------------------------------------------------------------------

def test_the_plan_a_simulated_run_records_is_the_plan_of_every_other_path(noisy_run, tmp_path):
    # bench run --sim, the TUI and a hardware run of the same plan compile the same steps, with the same commanded
    # values and estimates; the log records them and the plan's estimate (what --resume compares)
    from bench.tui.app import create_app

    text = noisy_run.text
    hardware = parse_config(text.replace('url = "sim"', 'url = "tcp://127.0.0.1:5000"', 1))
    assert not hardware.table.is_sim
    plan = compile_from_config(parse_config(text))
    assert compile_from_config(hardware).steps == plan.steps
    tui = create_app(config=parse_config(text), auto_connect=False, out_dir=tmp_path)
    assert tui.session.plan.steps == plan.steps and tui.session.plan.estimated_total_s == plan.estimated_total_s
    log = read_log(noisy_run.log)
    expected = [json.loads(json.dumps(step_to_dict(s))) for s in plan.steps]
    assert [e.step for e in log.events if isinstance(e, StepStarted)] == expected
    assert json.loads(log.metadata["plan"]["steps_json"]) == expected
    assert log.metadata["plan"]["estimated_total_s"] == f"{plan.estimated_total_s:.1f}"


def test_the_progress_of_a_simulated_run_goes_by_the_simulators_timing(noisy_run):
    # the plan's own estimates stay in the plan; the progress takes the re-timed ones
    from bench.cli.progress import ProgressPrinter

    config = parse_config(noisy_run.text)
    plan = compile_from_config(config)
    estimates = retime(plan.steps, timing_profile(config, sim=True))
    printer = ProgressPrinter(plan.steps, io.StringIO(), live=False, estimates=estimates)
    assert printer.total_s == pytest.approx(sum(estimates))
    assert sum(estimates) < plan.estimated_total_s       # the simulator moves faster than [plan]'s profile


# -- the model ------------------------------------------------------------------------------------------------------

def test_the_configured_profile_gives_the_plans_own_move_and_turn_estimates():
    config = parse_config(config_text(url="tcp://127.0.0.1:5000"))
    plan = compile_from_config(config)
    assert retime(plan.steps, timing_profile(config, sim=False)) == pytest.approx(
        [s.estimated_s for s in plan.steps], abs=1e-9)


def test_a_soak_with_an_instant_imu_is_the_airs_change_plus_the_stable_time():
    config = parse_config(thermal_config_text("[24.0, 30.0]"))
    plan = compile_from_config(config)
    chamber = [s for s in plan.steps if isinstance(s, (SetTemperatureStep, SoakStep))]
    # the air at 2 degC/min from 23 degC, an IMU that does not lag it (its rate is 0): within the tolerance
    # (1 degC) of the setpoint and the rate window (nearly) covered, then the stable time
    profile = TimingProfile("test", (50.0,) * 3, (50.0,) * 3, 0.0, 0.0,
                            SoakModel(2.0, imu_time_constant_s=None, start_air_c=23.0, start_imu_c=23.0))
    estimates = retime(chamber, profile)
    stable_s, window_s = chamber[1].stable_s, chamber[1].rate_window_s
    assert estimates[1] == pytest.approx(0.9 * window_s + stable_s, abs=1.0)          # 24 degC: the air is there
    assert estimates[3] == pytest.approx((30.0 - 1.0 - 24.0) / 2.0 * 60.0 + stable_s, abs=1.0)


def test_a_lagging_imu_soaks_longer_and_a_soak_never_exceeds_its_maximum():
    config = parse_config(thermal_config_text("[24.0, 60.0]"))
    plan = compile_from_config(config)
    chamber = [s for s in plan.steps if isinstance(s, (SetTemperatureStep, SoakStep))]
    fast = TimingProfile("t", (50.0,) * 3, (50.0,) * 3, 0.0, 0.0, SoakModel(2.0, imu_time_constant_s=60.0))
    slow = TimingProfile("t", (50.0,) * 3, (50.0,) * 3, 0.0, 0.0, SoakModel(2.0, imu_time_constant_s=1200.0))
    assert retime(chamber, slow)[3] > retime(chamber, fast)[3]
    assert all(e <= s.max_soak_s for e, s in zip(retime(chamber, slow), chamber) if isinstance(s, SoakStep))


def test_the_tuis_progress_of_a_simulated_run_goes_by_the_simulators_timing(noisy_run, tmp_path):
    # the TUI's plan table, progress and start dialog took the plan's own estimates (the Start dialog said "about
    # 4.5 min" of a run the simulator does in 4.0)
    from bench.tui.app import create_app

    config = parse_config(noisy_run.text)
    app = create_app(config=config, auto_connect=False, out_dir=tmp_path)
    expected = retime(app.session.plan.steps, timing_profile(config, sim=True))
    assert app.buffer.estimates == pytest.approx(expected)
    assert app.buffer.total_estimated_s == pytest.approx(_simulated_s(noisy_run.log), rel=0.01)
    assert f"about {sum(expected) / 60:.1f} min" in app.session.describe_plan()
