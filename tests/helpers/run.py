"""Shared pieces of the `bench run` end-to-end tests (tests/e2e/test_run.py).

A short plan (optimal-24 + optimal-5s6r, 3 s dwells, 50 Hz IMU) keeps one simulated run
at a few seconds of wall time; runs are driven through the CLI in-process
(`bench.cli.main.main`), as a subprocess (for signals) or through `BenchRun` (for fault
injection from a listener).
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import math
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Callable

from mcap.reader import make_reader

from bench.config.load import parse_config
from bench.log.events import RunListener
from bench.model.families import family_of
from bench.model.imu import NoiseModel
from bench.run.devices import SIMULATOR
from bench.run.runner import BenchRun, compile_from_config
from bench.sim.acquire import AcquisitionTiming, acquire
from bench.sim.imu import SimImu
from bench.sim.table import SimTable
from bench.solve.calibrate import solve
from drivers.turntable import AxisMode, AxisStatus

AT_REST_DPS = 1e-9

REPO = Path(__file__).resolve().parents[2]
DWELL_S = 3.0
RATE_HZ = 50.0
#: The CAN signals' resolution (counts): the simulated IMU's increments are quantised to it
#: sigma-delta style, so a dwell's summed counts are exact to within one step.
CAN_RESOLUTION_COUNTS = 1.0 / 256.0
NOMINAL_KA = 40000.0   # counts/s per g, the simulated accelerometers' scale (to 1e-3)
NOMINAL_KG = 36000.0   # counts/s per deg/s, the simulated gyros' scale

CONFIG = """\
format = "turntable-bench/config"
version = 1
[site]
latitude_deg = 30.27
[table]
url = "{url}"
dialect = "{dialect}"
timeout_s = 1.0   # long: a loaded machine must not turn a slow simulator into a timeout (0.2 s failed at load 12-15)
[imu]
interface = "virtual"
channel = "turntable-bench-test"
rate_hz = {rate_hz}
[imu.identity]
model = "test IMU"
serial = "T-0001"
[plan]
positions = "{positions}"
rotations = "{rotations}"
dwell_s = {dwell_s}
settle_s = 1.0
rest_s = 1.0
turn_rate_dps = 30.0
turn_accel_dps2 = 20.0
move_rate_dps = 60.0
move_accel_dps2 = 40.0
[sim]
seed = {seed}
black_box_arcsec = {black_box_arcsec}
noise = {noise}
"""


def config_text(*, url: str = "sim", dialect: str = "scpi", positions: str = "optimal-24",
                rotations: str = "optimal-5s6r", seed: int = 1, black_box_arcsec: float = 0.0,
                noise: str = "false", dwell_s: float = DWELL_S, rate_hz: float = RATE_HZ) -> str:
    """The short test plan's configuration TOML (noise off, ideal table unless told)."""
    return CONFIG.format(url=url, dialect=dialect, positions=positions, rotations=rotations, seed=seed,
                         black_box_arcsec=black_box_arcsec, noise=noise, dwell_s=dwell_s, rate_hz=rate_hz)


def noise_free_floor(family_name: str, dwell_s: float = DWELL_S) -> float:
    """Bound on a coefficient's error from the CAN resolution alone (noise off, ideal table).

    A dwell's mean rate is exact to one resolution step over the dwell, e = q/T counts/s;
    the position-method estimates are averages of such means (weights of l1 norm ~1),
    so Ka (relative), Ea and K0 (g) are good to e/Ka and D0 to e/Kg. The turns integrate
    ~1.3e7 counts to within one step: Kg and Eg are limited by other terms (1e-8 here).
    """
    e = CAN_RESOLUTION_COUNTS / dwell_s
    return {"Ka": e / NOMINAL_KA, "Ea": e / NOMINAL_KA, "K0": e / NOMINAL_KA,
            "D0": e / NOMINAL_KG * 3600.0, "Kg": 1e-8, "Eg": 1e-8}[family_name]


def coefficient_error(name: str, value: float, reference: float) -> float:
    """|value - reference|, relative for scale factors (Kg, Ka), absolute (display units) otherwise."""
    diff = abs(value - reference)
    return diff / abs(reference) if family_of(name) in ("Kg", "Ka") else diff


def values(result_json: dict, section: str = "coefficients") -> dict[str, float]:
    table = result_json[section] if section == "coefficients" else result_json[section]["coefficients"]
    return {name: entry["value"] for name, entry in table.items()}


def mismatches(actual: dict[str, float], reference: dict[str, float],
               tolerance: Callable[[str], float]) -> list[str]:
    """One line per coefficient of `reference` that `actual` misses by more than `tolerance(family)`."""
    out = []
    for name, ref in reference.items():
        err = coefficient_error(name, actual[name], ref)
        tol = tolerance(family_of(name))
        if not err <= tol:
            out.append(f"{name}: {actual[name]!r} vs {ref!r} (error {err:.3g} > {tol:.3g})")
    return out


class Trigger(RunListener):
    """Calls `action(run)` once, when step `step_index` starts or, with `moving_dps`, at the
    first table state during that step with an axis turning faster than that."""

    def __init__(self, step_index: int, action: Callable[[BenchRun], None], *, moving_dps: float | None = None):
        self.step_index, self.action, self.moving_dps = step_index, action, moving_dps
        self.run: BenchRun | None = None
        self.fired_at_s: float | None = None
        self._in_step = False

    def on_event(self, event) -> None:
        if event.kind == "step_started":
            self._in_step = event.step_index == self.step_index
            if self._in_step and self.moving_dps is None:
                self._fire(event.time_s)
        elif event.kind == "step_finished":
            self._in_step = False

    def on_table_state(self, state) -> None:
        if (self._in_step and self.moving_dps is not None
                and max(abs(r) for r in state.rates_dps) > self.moving_dps):
            self._fire(state.time_s)

    def _fire(self, time_s: float) -> None:
        if self.fired_at_s is None:
            self.fired_at_s = time_s
            self.action(self.run)


def step_index(plan, kind: str, nth: int = 0) -> int:
    """Index of the `nth` (0-based) step of `kind` in the compiled plan."""
    return [s.index for s in plan.steps if s.kind == kind][nth]


@contextlib.contextmanager
def api_run(text: str, out_dir: Path, *listeners: RunListener):
    """Open, run and finish a simulated `BenchRun` of config `text`; yields (run, outcome)
    with the simulated world still open (closed on exit)."""
    config = parse_config(text, source=str(out_dir / "bench.toml"), base_dir=out_dir)
    plan = compile_from_config(config)
    run = BenchRun(config, plan, devices=SIMULATOR, out_dir=out_dir, operator="api", listeners=listeners)
    for listener in listeners:
        listener.run = run
    with run:
        run.open()
        run.run()
        yield run, run.finish()


def record_short_run(out_dir: Path) -> tuple[Path, float]:
    """A finished simulated run of the shortest plan (traditional-12 + traditional-3s6r, 1 s dwells):
    (its log, the run clock's time when it finished)."""
    text = config_text(positions="traditional-12", rotations="traditional-3s6r", dwell_s=1.0)
    with api_run(text, out_dir) as (run, outcome):
        assert outcome.error is None, outcome.error
        finished_s = run.clock.now()
    return outcome.log_path, finished_s


def thermal_plan_text(temperatures_c: str, sections: str, serial: str = "T-0001") -> str:
    """The shortest plan (traditional-12 + traditional-3s6r, 1 s dwells) at `temperatures_c` (a TOML list), with
    `sections` (the soak, the chamber, the thermal IMU) after it."""
    return config_text(positions="traditional-12", rotations="traditional-3s6r", dwell_s=1.0).replace(
        'serial = "T-0001"', f'serial = "{serial}"').replace(
        "[plan]\n", f"[plan]\ntemperatures_c = {temperatures_c}\n", 1) + sections


def thermal_config_text(temperatures_c: str = "[24.0, 26.0]", rate_c_per_min: float = 0.5,
                        serial: str = "T-0001") -> str:
    """`thermal_plan_text` with the simulated chamber speaking Modbus RTU on a pty with `--sim`, a short soak, an
    IMU whose gyro x scale factor depends on its temperature."""
    return thermal_plan_text(temperatures_c, serial=serial, sections=f"""
[plan.soak]
rate_c_per_min = {rate_c_per_min}
stable_min = 1.0

[chamber]
url = "modbus+rtu:///dev/ttyUSB0?baud=115200"
poll_s = 5.0
safe_setpoint_c = 23.0

[sim.imu.thermal]
time_constant_s = 60.0
Kg_x = [0.36]
""")


def record_thermal_run(out_dir: Path, serial: str = "T-0001") -> Path:
    """`bench run --sim` of `thermal_config_text()` (24 and 26 degC; about 7 s) into `out_dir`: its log."""
    out_dir.mkdir(parents=True, exist_ok=True)
    config = out_dir / "bench.toml"
    config.write_text(thermal_config_text(serial=serial), encoding="utf-8")
    rc, _, stderr = cli(["run", "--config", str(config), "--sim", "--out", str(out_dir), "--quiet", "--no-db"])
    assert rc == 0, stderr
    return only_file(out_dir, "*.mcap")


def cli(argv: list[str]) -> tuple[int, str, str]:
    """`bench ...` in-process: (exit code, stdout, stderr)."""
    from bench.cli.main import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(argv)
    return rc, out.getvalue(), err.getvalue()


def start_cli(*args: str) -> subprocess.Popen:
    """`python -m bench.cli ...` as a subprocess in the repository root."""
    return subprocess.Popen([sys.executable, "-m", "bench.cli", *args], cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def stop_process(proc: subprocess.Popen) -> None:
    """Make sure a test's subprocess is gone (kill it if it still runs)."""
    if proc.poll() is None:
        proc.kill()
    try:
        proc.communicate(timeout=10)
    except (subprocess.TimeoutExpired, ValueError):
        pass


def wait_for(predicate: Callable[[], object], timeout_s: float, what: str, period_s: float = 0.05,
             proc: subprocess.Popen | None = None):
    """Poll `predicate` until it returns something truthy (bounded in time and count)."""
    deadline = time.monotonic() + timeout_s
    for _ in range(int(math.ceil(timeout_s / period_s)) + 1):
        value = predicate()
        if value:
            return value
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f"the process ended (exit code {proc.returncode}) before {what}")
        if time.monotonic() > deadline:
            break
        time.sleep(period_s)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


def only_file(folder: Path, pattern: str) -> Path:
    found = sorted(folder.glob(pattern))
    assert len(found) == 1, f"expected one {pattern} in {folder}, found {[p.name for p in found]}"
    return found[0]


def transitions(events) -> list[str]:
    return [e.state for e in events if e.kind == "transition"]


def assert_disabled(controller, *, at_rest: bool) -> None:
    state = controller.state()
    for axis in state.axes:
        assert not axis.status & AxisStatus.ENABLED, state
        assert axis.mode is AxisMode.OFF, state
        if at_rest:
            assert abs(axis.rate_dps) < AT_REST_DPS, state


def read_all_messages(path: Path) -> tuple[Counter, object, dict, dict]:
    """Every message through the mcap library with CRC validation: (per-topic counts,
    summary, metadata by name, attachments by name)."""
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        counts: Counter = Counter()
        for _schema, channel, message in reader.iter_messages():
            counts[channel.topic] += 1
            if channel.message_encoding == "json":
                json.loads(message.data)
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        attachments = {a.name: a for a in reader.iter_attachments()}
    return counts, summary, metadata, attachments


def assert_mcap_readable(path: Path) -> None:
    counts, summary, _, _ = read_all_messages(path)
    assert summary is not None and summary.statistics is not None
    expected = Counter({summary.channels[cid].topic: n
                        for cid, n in summary.statistics.channel_message_counts.items() if n})
    assert counts == expected


def in_memory_result(config) -> dict:
    """The same schedules through the in-memory acquisition (same black box, same IMU, no noise),
    solved with equal weights: without noise the dwells' standard errors are float round-off
    (~1e-12 counts/s, all but random), and weighting by them distorts a black-box solution."""
    p = config.plan
    timing = AcquisitionTiming(dwell_s=p.dwell_s, settle_s=p.settle_s, move_rate_dps=p.move_rate_dps,
                               move_accel_dps2=p.move_accel_dps2, turn_rate_dps=p.turn_rate_dps,
                               turn_accel_dps2=p.turn_accel_dps2, rest_s=p.rest_s)
    site = config.site.site
    table = SimTable(site, black_box_rad=config.sim.black_box_rad)
    imu = SimImu(config.sim.imu, NoiseModel.off(), rate_hz=config.imu.rate_hz)
    positions, rotations = acquire(table, imu, [s.angles_deg for s in p.positions.positions],
                                   list(p.rotations.rotations), timing)
    unweighted = [dataclasses.replace(o, gyro_sem=None, acc_sem=None, gyro_std=None, acc_std=None)
                  for o in positions]
    return solve(unweighted, rotations, site).to_result(sim_truth=config.sim.imu).to_json()


def results_below(folder: Path) -> dict[str, dict]:
    """Every result file below `folder` (by path relative to it), parsed, without `run.solved_utc` (when it was
    solved: differs by design)."""
    out = {}
    for p in sorted(folder.rglob("*.result.json")):
        data = json.loads(p.read_bytes())
        data["run"].pop("solved_utc")
        out[str(p.relative_to(folder))] = data
    return out


def load_json(path: Path) -> dict:
    return json.loads(path.read_text(encoding="utf-8"))


def kill_run_after_units(config: Path, out: Path, units: int = 5) -> tuple[Path, dict]:
    """Start `bench run --config` as a process, SIGKILL it once its log holds `units` finished
    observation steps; returns the killed log and those steps (unit -> events)."""
    from bench.log.events import finished_observation_steps
    from bench.log.reader import LogError, read_log

    seen: dict = {}

    def enough_units_in_log():
        logs = list(out.glob("*.mcap"))
        if not logs:
            return None
        try:
            finished = finished_observation_steps(read_log(logs[0]).events)
        except LogError:
            return None
        if len(finished) >= units:
            seen.update(finished)
            return logs[0]
        return None

    proc = start_cli("run", "--config", str(config), "--out", str(out), "--quiet")
    try:
        killed = wait_for(enough_units_in_log, 60.0, f"{units} finished observation steps in the log",
                          period_s=0.1, proc=proc)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        stop_process(proc)
    assert proc.returncode == -signal.SIGKILL
    return killed, seen
