"""The chamber-driven calibration over temperature end to end (issue 18 items 3 and 5, "must show").

`bench run --config thermal.example.toml --sim --out runs/thermal-run` (docs/how-to/thermal.md, run as the page's
test runs it, once per session: `documented_thermal_run`): the simulated chamber (ASCII dialect over
loopback) goes to -20, 0, 25 and 50 degC, its air drives the thermal IMU's case (time
constant 120 s), each temperature is soaked on the IMU's own temperature and calibrated with
the default schedules (short 20 s dwells, 100 Hz), all on the simulated clock in one log. The
run then solves one calibration per temperature from the log and fits the thermal model; the
fitted polynomials must recover the configured ones within their uncertainty, as
tests/e2e/test_thermal_run.py checks for the in-memory `bench thermal sim`. One seed (0, the
example's); on seed 2 the short run misses D0_x's small quadratic term, a 3.4-sigma effect the
1 % degree test finds in 82 % of runs (docs/how-to/thermal.md, "How well the degrees are found";
studies/thermal_degree_power.py): that limit is known, not hidden by this test.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from mcap.reader import make_reader

from bench.config.load import parse_config
from bench.log.events import Info, StepFinished
from bench.log.reader import read_log
from bench.model.result import CalibrationResult
from bench.thermal.model import ThermalModel
from tests.helpers.run import cli, only_file

#: the documented example (docs/how-to/thermal.md): the shipped thermal.example.toml
THERMAL_RUN_TOML = (Path(__file__).resolve().parents[2] / "thermal.example.toml").read_text(encoding="utf-8")
TEMPERATURES_C = (-20.0, 0.0, 25.0, 50.0)
Z_LIMIT = 3.0
# a bound on a hung run, not a speed check: about 2 min of CPU, far longer on a loaded machine
pytestmark = pytest.mark.timeout(1800)


@pytest.fixture
def thermal_run(documented_thermal_run):
    """The documented run, as the page's test runs it (recorded once per session: tests/conftest.py)."""
    return parse_config(THERMAL_RUN_TOML), documented_thermal_run.out, documented_thermal_run.stdout

def _true_degree(terms) -> int:
    return max([0] + [k for k, c in enumerate(terms, start=1) if c != 0.0])


def test_one_run_calibrates_at_every_temperature_and_recovers_the_thermal_polynomials(thermal_run,
                                                                                     documented_thermal_run):
    config, out, stdout = thermal_run
    model = ThermalModel.load(only_file(out, "*.thermal.json"))
    assert [p.temperature_c for p in model.points] == pytest.approx(TEMPERATURES_C, abs=0.3)
    thermal = config.sim.thermal
    for name, fit in model.fits.items():
        truth = model.sim_truth[name]
        if name in thermal.polynomials:           # every configured term found, its value at 25 degC right
            assert fit.degree >= _true_degree(thermal.polynomials[name]), (name, fit.chi2_by_degree)
            assert abs(fit.polynomial[0] - truth[0]) < Z_LIMIT * fit.sigma[0], name
        for k in range(1, fit.degree + 1):        # and every fitted temperature term within its uncertainty
            z = (fit.polynomial[k] - truth[k]) / fit.sigma[k]
            assert abs(z) < Z_LIMIT, (name, k, fit.polynomial[k], truth[k], fit.sigma[k])
    # the terms are far above their uncertainty: a model that ignored temperature would fail
    kg = model.fits["Kg_x"]
    assert kg.degree == 1 and abs(kg.polynomial[1]) > 10 * kg.sigma[1]
    # the files next to the run's result: one result per temperature, the model and its reports
    model_path = only_file(out, "*.thermal.json").relative_to(documented_thermal_run.cwd)    # as --out was given
    assert "thermal: " in stdout and str(model_path) in stdout
    assert len(list(out.glob("*.T?.result.json"))) == 4
    assert only_file(out, "*.thermal.html").stat().st_size > 0 and only_file(out, "*.thermal.md").stat().st_size > 0


def test_each_temperature_is_its_own_calibration_told_apart_by_its_units(thermal_run):
    _, out, _ = thermal_run
    results = {int(p.name.split(".T")[1][0]): CalibrationResult.load(p) for p in out.glob("*.T?.result.json")}
    for k, setpoint in enumerate(TEMPERATURES_C, start=1):
        result = results[k]
        assert result.run.extra["temperature_block"] == k and result.run.extra["temperature_setpoint_c"] == setpoint
        t = result.temperature
        assert t["setpoint_c"] == setpoint and abs(t["mean_c"] - setpoint) < 0.5 and t["max_c"] - t["min_c"] < 1.0
        labels = [r["label"] for r in result.residuals["positions"]] if "positions" in result.residuals else []
        assert all(label.startswith(f"T{k}-") for label in labels)
    # the run's own result (verdict, reports) is the calibration nearest the model's reference, 25 degC
    main = CalibrationResult.load(only_file(out, "[0-9]*Z-??????.result.json"))
    assert main.run.extra["thermal"]["this_block"] == 3 and main.temperature["setpoint_c"] == 25.0


def test_the_log_records_the_chamber_state_and_every_soak_decision(thermal_run):
    _, out, _ = thermal_run
    log_path = only_file(out, "*.mcap")
    with open(log_path, "rb") as f:
        states = [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(topics=["/chamber/state"])]
    assert len(states) > 100 and {"temperature_c", "setpoint_c", "running", "alarms"} <= set(states[0])
    assert min(s["temperature_c"] for s in states) < -19.0 and max(s["temperature_c"] for s in states) > 49.0
    events = read_log(str(log_path)).events
    soaks = [e for e in events if isinstance(e, StepFinished) and e.step_kind == "soak"]
    assert [e.step["setpoint_c"] for e in soaks] == list(TEMPERATURES_C)
    for e in soaks:
        assert abs(e.soak.rate_c_per_min) < 0.1 and e.soak.steady_for_s >= 180.0
    decisions = [e.soak.decision for e in events if isinstance(e, Info) and e.soak is not None]
    assert decisions.count("done") == 4 and decisions.count("imu_settling") >= 4
    assert events[-2].details.get("chamber") == "made_safe" and "23 degC" in events[-2].message


def test_bench_solve_re_solves_every_temperature_and_refits_the_model_as_the_run_did(thermal_run, tmp_path):
    """`bench solve THERMAL_LOG`: the run's outputs again under `<run-id>.solved` (nothing overwritten), every
    temperature's calibration and the thermal model exactly the run's."""
    _, out, _ = thermal_run
    rc, stdout, stderr = cli(["solve", str(only_file(out, "*.mcap")), "--out", str(tmp_path), "--no-html"])
    assert rc == 0, stderr
    assert "4 temperatures, one calibration each" in stdout and "thermal: " in stdout
    assert_same_thermal_outputs(out, tmp_path)


def assert_same_thermal_outputs(run_out: Path, solved_out: Path) -> None:
    """The re-solve's per-temperature results, model and headline result are the run's, number for number."""
    run_results = sorted(run_out.glob("*Z-??????.T?.result.json"))
    solved_results = sorted(solved_out.glob("*.solved.T?.result.json"))
    assert len(solved_results) == len(run_results) >= 1
    for ran, solved in zip(run_results, solved_results):
        a, b = CalibrationResult.load(ran), CalibrationResult.load(solved)
        assert a.coefficients == b.coefficients and a.temperature == b.temperature, ran.name
    models = [list(d.glob(pattern)) for d, pattern in ((run_out, "*Z-??????.thermal.json"),
                                                       (solved_out, "*.solved.thermal.json"))]
    assert len(models[0]) == len(models[1]) == (len(run_results) > 1)      # a model from two temperatures on
    if models[0]:
        run_model, solved_model = ThermalModel.load(models[0][0]), ThermalModel.load(models[1][0])
        assert run_model.model_json() == solved_model.model_json()
        assert solved_model.run["solved_by"] == "bench solve"
    head, solved_head = (CalibrationResult.load(only_file(d, pattern))
                         for d, pattern in ((run_out, "*Z-??????.result.json"), (solved_out, "*.solved.result.json")))
    assert head.coefficients == solved_head.coefficients
    assert head.run.extra["thermal"]["this_block"] == solved_head.run.extra["thermal"]["this_block"]


def test_a_thermal_run_cut_off_resumes_without_soaking_the_finished_temperature_again(tmp_path):
    """Aborted at the second temperature's first dwell; `--resume` skips the first temperature whole (its
    set-temperature and soak too), soaks the second again and solves both temperatures from both logs."""
    from bench.run.devices import SIMULATOR
    from bench.run.resume import resume_point
    from bench.run.runner import BenchRun, compile_from_config
    from tests.helpers.run import Trigger, api_run, config_text

    text = config_text(positions="traditional-12", rotations="traditional-3s6r", dwell_s=2.0).replace(
        "[plan]\n", "[plan]\ntemperatures_c = [20.0, 30.0]\n", 1) + """
[plan.soak]
rate_c_per_min = 0.1
stable_min = 2.0

[chamber]
url = "sim"
dialect = "ascii"
safe_setpoint_c = 23.0

[sim.imu.thermal]
time_constant_s = 60.0
Kg_x = [0.36]
"""
    config = parse_config(text, source=str(tmp_path / "bench.toml"), base_dir=tmp_path)
    plan = compile_from_config(config)
    second = next(s.index for s in plan.steps if s.kind == "dwell" and s.unit.startswith("T2-"))
    trigger = Trigger(second, lambda run: run.abort("cut off"))
    with api_run(text, tmp_path, trigger) as (_, outcome):
        assert outcome.error is not None and str(outcome.error) == "cut off"
    resumed = resume_point(outcome.log_path, config, plan, sim=True)
    assert resumed.completed and all(u.startswith("T1-") for u in resumed.completed)
    assert len(resumed.completed) == len([s for s in plan.steps if s.kind in ("dwell", "turn")]) // 2
    out = tmp_path / "resumed"
    with BenchRun(config, plan, devices=SIMULATOR, out_dir=out, completed=resumed.completed,
                  previous_logs=resumed.previous_logs) as run:
        run.open()
        run.run()
        done = run.finish()
    assert done.error is None and done.thermal_model is not None
    assert [round(p.temperature_c) for p in done.thermal_model.points] == [20, 30]
    events = read_log(str(done.log_path)).events
    skipped = {e.step_unit for e in events if e.kind == "step_skipped"}
    assert "T1" in skipped and "T2" not in skipped
    soaked = [e.step["setpoint_c"] for e in events if isinstance(e, StepFinished) and e.step_kind == "soak"]
    assert soaked == [30.0]


def test_a_thermal_run_over_the_modbus_rtu_chamber_and_its_re_solve(tmp_path):
    """The chamber url chooses the dialect and link: `modbus+rtu://...` with `--sim` is the simulated chamber
    speaking Modbus RTU on a pty (no dialect key). The smallest thermal plan (one temperature near the room's,
    the shortest schedules) runs through it: set, soak, polls, the chamber made safe at the end; `bench solve`
    on its log then gives the run's results again."""
    from bench.run.devices import SIMULATOR
    from bench.run.runner import BenchRun, compile_from_config
    from tests.helpers.run import thermal_config_text

    text = thermal_config_text("[24.0]", rate_c_per_min=0.1)
    config = parse_config(text, source=str(tmp_path / "bench.toml"), base_dir=tmp_path)
    assert config.chamber.dialect == "modbus"
    out = tmp_path / "run"
    with BenchRun(config, compile_from_config(config), devices=SIMULATOR, out_dir=out) as run:
        run.open()
        assert run.chamber.dialect == "modbus" and run.chamber.url.startswith("modbus+rtu:///dev/pts/")
        assert run.run().value == "done", run.sequencer.error
        outcome = run.finish()
        assert run.world.chamber.state().setpoint_c == 23.0            # made safe at the end, over RTU
    assert outcome.error is None and len(outcome.thermal_paths) == 1 and outcome.thermal_model is None
    events = read_log(str(outcome.log_path)).events
    assert [e.soak.decision for e in events if isinstance(e, Info) and e.soak is not None][-1] == "done"
    assert events[-2].details.get("chamber") == "made_safe"
    rc, stdout, stderr = cli(["solve", str(outcome.log_path), "--out", str(tmp_path / "solved"), "--no-html"])
    assert rc == 0, stderr
    assert "1 temperature, one calibration each" in stdout and "thermal: " not in stdout
    assert_same_thermal_outputs(out, tmp_path / "solved")

