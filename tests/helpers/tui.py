"""Shared helpers of the TUI pilot tests (tests/tui/test_tui*.py): the app on the simulator, bounded waits.

pytest-asyncio is not installed: each test runs its coroutine with `asyncio.run`. Every
wait is bounded in time and count.
"""

from __future__ import annotations

import asyncio
import math
import time
from pathlib import Path

import numpy as np

from bench.config.load import parse_config
from bench.log.events import RunState, make_event
from bench.model.quality_section import QualitySection
from bench.model.result import CalibrationResult, coefficient_table
from drivers.imu import ImuSampleBlock
from drivers.turntable import AxisMode, AxisState, AxisStatus, TableState
from tests.helpers.run import config_text

SIZE = (100, 30)


def make_config(tmp_path: Path, **kwargs):
    return parse_config(config_text(**kwargs), source=str(tmp_path / "bench.toml"), base_dir=tmp_path)


def make_app(tmp_path: Path, **kwargs):
    from bench.tui import create_app

    options = dict(config=make_config(tmp_path), sim=True, out_dir=tmp_path, refresh_hz=20.0, poll_s=0.05)
    options.update(kwargs)
    return create_app(**options)


async def wait_until(pilot, predicate, what: str, timeout_s: float = 15.0, period_s: float = 0.05):
    """Let the app run until `predicate()` is truthy (bounded in time and count)."""
    deadline = time.monotonic() + timeout_s
    for _ in range(int(timeout_s / period_s) + 1):
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            break
        await pilot.pause(period_s)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


async def press(pilot, key: str) -> None:
    """Send a key without waiting for the process to go idle: `Pilot.press` waits up to 2 s per
    key for that, and the simulator keeps the process busy."""
    pilot.app.simulate_key(key)
    await pilot.pause(0.05)


async def submit(pilot, dialog) -> None:
    """Enter in the go-to dialog's first field (what the Move button does)."""
    dialog.query_one("#goto-outer").focus()
    await press(pilot, "enter")


def run(coro_fn, *args):
    asyncio.run(coro_fn(*args))


def snap(app):
    return app.buffer.snapshot()


def events_text(app) -> str:
    return "\n".join(app.query_one("#event-log").plain_lines)


async def dialog_open(pilot, name: str, child: str):
    """Wait until dialog `name` is on top with its widgets mounted (`child` is one of them)."""
    app = pilot.app
    await wait_until(pilot, lambda: type(app.screen).__name__ == name and app.screen.query(child), f"the {name}")
    return app.screen


async def connected(pilot):
    app = pilot.app
    await wait_until(pilot, lambda: app.session.connected and snap(app).table_state is not None
                     and snap(app).imu.gyro_cps is not None, "connection and first table/IMU data")
    await pilot.pause(0.1)


async def start_plan(pilot):
    app = pilot.app
    await press(pilot, "s")
    await dialog_open(pilot, "ConfirmScreen", "#confirm-body")
    body = str(app.screen.query_one("#confirm-body").render())
    assert "ALL THREE AXES" in body and "steps" in body, body
    await press(pilot, "y")
    await wait_until(pilot, lambda: snap(app).run_state is RunState.RUNNING, "the run to start")


async def wait_ended(pilot):
    app = pilot.app
    await wait_until(pilot, lambda: not app.session.running, "the run to end", timeout_s=30.0)
    await pilot.pause(0.15)


def feed_running(app) -> None:
    """A run under way fed straight into the app's buffer (no wall-clock text, no run ids): for snapshots."""
    buf, steps = app.buffer, app.steps
    app.session.link, app.session.link_detail = "connected", "scpi, simulator"
    buf.on_event(make_event(0.0, "transition", "run started: %d steps" % len(steps), state="running",
                       data={"from": "idle"}))
    t = 0.0
    dwell = [s for s in steps if s.kind == "dwell"][2]
    for s in steps[:dwell.index]:
        buf.on_event(make_event(t, "step_started", f"{s.unit} {s.kind}", step_index=s.index, step_unit=s.unit))
        t += s.estimated_s
        buf.on_event(make_event(t, "step_finished", f"{s.unit} {s.kind} done in {s.estimated_s:.1f} s",
                           step_index=s.index, step_unit=s.unit))
    buf.on_event(make_event(t, "step_started", f"{dwell.unit} dwell", step_index=dwell.index, step_unit=dwell.unit))
    enabled = AxisStatus.ENABLED | AxisStatus.IN_POSITION
    buf.on_table_state(TableState(t + 1.0, tuple(AxisState(a, 0.0, AxisMode.POSITION, enabled)
                                                 for a in dwell.target_deg)))
    n = 40
    k = np.arange(n)
    g = (np.array([0.5, -0.25, 0.1]) * 36000.0)[None, :] + 50.0 * np.sin(k / 4.0)[:, None]
    a = (np.array([0.0, 0.0, 1.0]) * 40000.0)[None, :] + 20.0 * np.cos(k / 5.0)[:, None]
    block = ImuSampleBlock(k.astype(np.int64), k / 50.0, g / 50.0, a / 50.0, np.full(n, 24.5),
                           np.zeros(n, np.int64), 50.0)
    buf.on_imu(block)


def feed_result(app) -> None:
    """A finished run's result (the simulator's truth, each value off by a few tenths to a few sigma)."""
    truth = app.session.config.sim.imu.to_canonical()
    sigmas = {name: (abs(v) * 1e-6 if abs(v) > 1 else 1e-6) for name, v in truth.items()}
    offsets = (0.4, -1.3, 2.6, 0.0, -0.7)
    values = {name: v + offsets[k % len(offsets)] * sigmas[name] for k, (name, v) in enumerate(truth.items())}
    result = CalibrationResult(coefficient_table(values, sigmas), sim_truth=coefficient_table(truth))
    app.buffer.on_event(make_event(300.0, "transition", "run complete", state="done", data={"from": "running"}))
    app.buffer.set_outcome(result, "done; result run.result.json")


def feed_budget_result(app, table_included: bool = False) -> None:
    """A finished run's result with an uncertainty budget per coefficient (noise and bias instability; with
    `table_included` a turntable part 3x the noise), the table's part not included unless asked, and the gyro x
    fit's residuals inconsistent with the budget (widened by 2.5 as a fallback)."""
    truth = app.session.config.sim.imu.to_canonical()
    noise = {name: (abs(v) * 1e-6 if abs(v) > 1 else 1e-6) for name, v in truth.items()}
    budgets = {name: {"noise": n, "bias instability": 0.5 * n, **({"turntable pointing": 3 * n} if table_included
                                                                    else {})} for name, n in noise.items()}
    sigmas = {name: math.sqrt(sum(v * v for v in b.values())) for name, b in budgets.items()}
    values = {name: v + 0.5 * sigmas[name] for name, v in truth.items()}
    table = {"source": "datasheet: pointing accuracy 5 arcsec (1-sigma)", "sigma_arcsec": [[5.0] * 3] * 3}
    quality = {"uncertainty": {"k": 2.0, "table_included": table_included,
                               "inputs": {"table": table if table_included else None},
                               "consistency": [{"fit": "gyros", "sensor": "x", "chi2": 40.0, "dof": 8, "p_value": 1e-5,
                                                "consistent": False, "scale": 2.5,
                                                "drivers": ["R03 (+5.2)", "R07 (-3.1)"]}]}}
    result = CalibrationResult(coefficient_table(values, sigmas, budgets, 2.0),
                               quality=QualitySection.from_dict(quality), sim_truth=coefficient_table(truth))
    app.buffer.on_event(make_event(300.0, "transition", "run complete", state="done", data={"from": "running"}))
    app.buffer.set_outcome(result, "done; result run.result.json")
