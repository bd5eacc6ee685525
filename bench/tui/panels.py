"""The main screen's panels. Each one redraws from a `UiSnapshot` when the app's timer ticks.

Panels keep the plain text they last drew (`plain`) so tests can read what the
operator sees without parsing the screen.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from rich.console import JustifyMethod
from rich.table import Table as RichTable
from rich.text import Text
from textual.app import ComposeResult
from textual.containers import Horizontal, Vertical
from textual.widget import Widget
from textual.widgets import DataTable, Label, ProgressBar, RichLog, Static

from bench.acceptance.verdict import stored_headline
from bench.log.events import RunState, StepStarted
from bench.model.families import family_of
from bench.model.kinematics import FRAMES
from bench.model.units import format_hms
from bench.plan.steps import thermal_block
from bench.report.facts import turn_angle_missing
from bench.tui.buffer import (
    CHANNELS,
    MEAN_WINDOW_S,
    ImuScales,
    LogLine,
    StepState,
    UiSnapshot,
    UnitView,
    progress,
    step_estimates,
)

DEG_PER_HOUR_PER_DPS = 3600.0
#: the IMU panel's title: what its values are
IMU_TITLE = f"IMU: means over {MEAN_WINDOW_S:g} s"


@dataclass(frozen=True)
class Palette:
    """Text colours for states, from the current theme's text-* variables (readable on its background)."""

    ok: str
    warn: str
    error: str


def palette(app) -> Palette:
    """The palette of `app`'s current theme (cached per theme name on the app)."""
    cache = app.__dict__.setdefault("_bench_palettes", {})
    name = app.theme
    found = cache.get(name)
    if found is None:
        v = app.get_css_variables()
        found = cache[name] = Palette(v.get("text-success", "green"), v.get("text-warning", "yellow"),
                                      v.get("text-error", "red"))
    return found


def set_text(label, text: str) -> None:
    """Update a Label/Static only when its text changes: every update costs the UI thread a layout pass."""
    if getattr(label, "_bench_text", None) != text:
        label._bench_text = text
        label.update(text)


def _limits_text(axis) -> str:
    span = "cont" if axis.min_deg is None or axis.max_deg is None else f"{axis.min_deg:g}..{axis.max_deg:g}"
    return f"{span} {axis.max_rate_dps:g}/s"


class TablePanel(Static):
    """Angles, rates, mode, servo, in-position and limits per axis; fault/e-stop and link status."""

    DEFAULT_CSS = "TablePanel { height: auto; padding: 0 1; }"

    def __init__(self, limits, **kwargs):
        super().__init__(**kwargs)
        self.limits = limits
        self.plain = ""
        self._drawn_with = None
        self.border_title = "Table"

    def show(self, snapshot: UiSnapshot, link: str, link_detail: str, jog: str = "") -> None:
        pal = palette(self.app)
        state = snapshot.table_state
        grid = RichTable.grid(padding=(0, 1))
        columns: tuple[tuple[str, JustifyMethod], ...] = (
            ("axis", "left"), ("angle deg", "right"), ("rate deg/s", "right"), ("mode", "left"), ("servo", "left"),
            ("in-pos", "left"), ("limits", "left"))
        for header, justify in columns:
            grid.add_column(header, justify=justify, no_wrap=True)
        rows = [("axis", "angle°", "rate°/s", "mode", "servo", "inpos", "limits")]
        short = {"position": "pos", "rate": "rate", "off": "off"}
        for k, name in enumerate(FRAMES):
            limit = _limits_text(self.limits.axes[k])
            if state is None:
                rows.append((name, "-", "-", "-", "-", "-", limit))
                continue
            axis = state.axes[k]
            rows.append((name, f"{axis.angle_deg:.4f}", f"{axis.rate_dps:.4f}",
                         short.get(axis.mode.value, axis.mode.value), "on" if axis.enabled else "off",
                         "yes" if axis.in_position else "no", limit))
        grid.add_row(*(Text(h, style="bold") for h in rows[0]))
        for row in rows[1:]:
            grid.add_row(*row[:4], Text(row[4], style=f"bold {pal.ok}" if row[4] == "on" else ""), *row[5:])
        if state is None:
            status = Text("no table state yet")
        elif state.estop or state.fault:
            status = Text(f"FAULT: {state.describe_fault()}", style=f"bold {pal.error}")
        else:
            status = Text("status: ok", style=pal.ok)
        link_style = {"connected": pal.ok, "replay": pal.ok, "error": f"bold {pal.error}"}.get(link, pal.warn)
        link_text = Text(f"link: {link}" + (f" ({link_detail})" if link_detail else ""), style=link_style)
        lines = [Text(""), status, link_text] + ([Text(jog)] if jog else [])
        plain = "\n".join([*("  ".join(r) for r in rows), status.plain, link_text.plain, jog])
        if plain != self.plain or pal is not self._drawn_with:
            self._drawn_with = pal
            self.update(_Stack(grid, Text("\n").join(lines)))
        self.plain = plain


class _Stack:
    """Two renderables one below the other."""

    def __init__(self, *parts):
        self.parts = parts

    def __rich_console__(self, console, options):
        yield from self.parts


#: a sparkline's eight levels, lowest first
TRACE_LEVELS = "▁▂▃▄▅▆▇█"
#: a trace spans at least this many standard errors of a cell's mean: a channel whose cells differ by no more
#: than their noise draws as a flat line about mid-height, not as a full-height bar
TRACE_NOISE_SPAN = 16.0


def trace_levels(data: Sequence[float], cells: int, floor: float = 0.0) -> list[int]:
    """The sparkline of `data` in `cells` cells (fewer samples than cells: each sample over several cells), as
    levels 0..7 (`TRACE_LEVELS`).

    Each cell is the mean of its share of the samples. Textual's Sparkline draws the maximum of each
    share on a scale from the smallest to the largest sample: a near-constant channel's noise then fills
    every cell to the top (a solid bar). Here the scale spans the cells' means, but at least `floor` (one
    resolution step per sample, counts/s) and `TRACE_NOISE_SPAN` standard errors of a mean (the scatter
    within the cells), centred on the means' midrange: a constant channel is a flat line, a move stands out.
    """
    x = np.asarray(data, dtype=float)
    x = x[np.isfinite(x)]
    if x.size == 0 or cells <= 0:
        return []
    if x.size < cells:
        each = trace_levels(x, x.size, floor)
        return [each[k * x.size // cells] for k in range(cells)]
    cell = np.arange(x.size) * cells // x.size          # each sample's cell (vectorised: 6 traces a frame)
    means = np.bincount(cell, x, cells) / np.bincount(cell, None, cells)
    scatter = math.sqrt(float(np.mean((x - means[cell]) ** 2)))
    lo, hi = float(means.min()), float(means.max())
    span = max(hi - lo, TRACE_NOISE_SPAN * scatter / math.sqrt(x.size / cells), floor)
    if not span > 0:
        return [3] * cells                      # all equal: the middle
    levels = np.floor((means - (lo + hi) / 2.0) / span * len(TRACE_LEVELS) + 3.5)
    return [int(k) for k in np.clip(levels, 0, len(TRACE_LEVELS) - 1)]


class Trace(Widget):
    """One channel's recent samples as a one-line sparkline (`trace_levels`)."""

    DEFAULT_CSS = "Trace { width: 1fr; height: 1; color: $primary; }"

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.data: tuple[float, ...] = ()
        self.floor = 0.0

    def show(self, data: tuple[float, ...], floor: float) -> None:
        if data != self.data or floor != self.floor:
            self.data, self.floor = data, floor
            self.refresh()

    @property
    def plain(self) -> str:
        """What it draws at its current width."""
        return "".join(TRACE_LEVELS[k] for k in trace_levels(self.data, self.size.width, self.floor))

    def render(self) -> Text:
        return Text(self.plain)


def format_age(seconds: float) -> str:
    """How long ago, in whole seconds up to 999 s, then h:mm:ss."""
    return f"{seconds:.0f} s" if seconds < 999.5 else format_hms(seconds)


class ImuPanel(Vertical):
    """Latest gyro (deg/s and deg/h) and accelerometer (g) per axis with a sparkline each, rate,
    temperature and link counters. Once no sample came for `STALE_AFTER_S` (a paused run, a paused or
    ended replay, a silent IMU) the values are dimmed and the first line says how old they are."""

    DEFAULT_CSS = """
    ImuPanel { height: auto; padding: 0 1; }
    ImuPanel .imu-row { height: 1; }
    ImuPanel .imu-value { width: 26; }
    ImuPanel.-stale .imu-value { text-style: dim; }
    ImuPanel.-stale Trace { text-style: dim; color: $foreground-muted; }
    """

    def __init__(self, scales: ImuScales, **kwargs):
        super().__init__(**kwargs)
        self.scales = scales
        self.plain = ""
        self._head_drawn: tuple[str, str] | None = None
        self.border_title = IMU_TITLE

    def compose(self) -> ComposeResult:
        yield Label("", id="imu-head")
        for ch in CHANNELS:
            with Horizontal(classes="imu-row"):
                yield Label("", id=f"imu-{ch}", classes="imu-value")
                yield Trace(id=f"spark-{ch}")
        yield Label(Text(self.scales.source, style="dim"), id="imu-units")

    def _value(self, k: int, cps: float | None) -> str:
        """One channel's mean (`MEAN_WINDOW_S`) with the decimals it resolves (`ImuScales.decimals`)."""
        name = CHANNELS[k]
        if cps is None or not math.isfinite(cps):
            return f"{name}  -"
        gyro = k < 3
        scale = self.scales.gyro_cps_per_dps if gyro else self.scales.acc_cps_per_g
        if scale is None:
            return f"{name} {cps:14.{self.scales.decimals(gyro, 1.0, 3)}f} counts/s"
        if gyro:
            dps = cps / scale[k]
            d_dps = self.scales.decimals(True, 1.0 / scale[k], 5)
            d_dph = self.scales.decimals(True, DEG_PER_HOUR_PER_DPS / scale[k], 3)
            return f"{name} {dps:9.{d_dps}f} {dps * DEG_PER_HOUR_PER_DPS:10.{d_dph}f}"
        return f"{name} {cps / scale[k - 3]:9.{self.scales.decimals(False, 1.0 / scale[k - 3], 6)}f} g"

    def show(self, snapshot: UiSnapshot, unit: UnitView | None = None, title: str = IMU_TITLE,
             scales: ImuScales | None = None) -> None:
        """Draw the IMU, or with `unit` that unit of a run of several (its own `title` and `scales`)."""
        imu = snapshot.imu if unit is None else unit.imu
        if scales is not None:
            self.scales = scales
        if title != self.border_title:
            self.border_title = title
        if unit is not None and unit.dropped:
            head = Text(unit.state, style=f"bold {palette(self.app).error}")
        elif imu.stale and imu.age_s is not None:
            head = Text(f"stale: no sample for {format_age(imu.age_s)}", style=f"bold {palette(self.app).warn}")
        else:
            rate = f"{imu.rate_hz:g} Hz" if math.isfinite(imu.rate_hz) else "- Hz"
            temp = f"{imu.temperature_c:.1f} C" if math.isfinite(imu.temperature_c) else "- C"
            head = Text(f"{rate}  {temp}  lost {imu.lost_samples}  bad frames {imu.bad_frames}")
        self.set_class(imu.stale, "-stale")
        drawn = (head.plain, str(head.style))
        if drawn != self._head_drawn:          # (an update costs a layout pass: only on a change)
            self._head_drawn = drawn
            self.query_one("#imu-head", Label).update(head)
        values = (imu.gyro_cps or (None,) * 3) + (imu.acc_cps or (None,) * 3)
        lines = [title, head.plain]
        for k, ch in enumerate(CHANNELS):
            text = self._value(k, values[k])
            lines.append(text)
            set_text(self.query_one(f"#imu-{ch}", Label), text)
            step = self.scales.step_counts[0 if k < 3 else 1]
            floor = step * imu.rate_hz if math.isfinite(imu.rate_hz) else 0.0   # one step per sample, counts/s
            self.query_one(f"#spark-{ch}", Trace).show(imu.history[k], floor)
        lines.append(self.scales.source)
        self.plain = "\n".join(lines)


def describe_step(step) -> str:
    if step.kind == "move":
        return "to " + ", ".join(f"{a:g}" for a in step.target_deg)
    if step.kind == "settle":
        return f"{step.duration_s:g} s"
    if step.kind == "dwell":
        return f"{step.dwell_s:g} s at " + ", ".join(f"{a:g}" for a in step.angles_deg)
    if step.kind == "turn":
        return f"{step.frame} {step.direction} x{step.revolutions} @ {step.rate_dps:g}/s"
    if step.kind == "set_temperature":
        return f"chamber to {step.setpoint_c:g} degC"
    if step.kind == "soak":
        return f"IMU < {step.rate_c_per_min:g} degC/min for {step.stable_s / 60.0:g} min"
    return ""


def state_style(state: StepState, pal: Palette) -> str:
    return {StepState.RUNNING: f"bold {pal.warn}", StepState.DONE: pal.ok, StepState.FAILED: f"bold {pal.error}",
            StepState.ABORTED: f"bold {pal.warn}"}.get(state, "dim")


class PlanPanel(Vertical):
    """The compiled steps with their state, the current step with its countdown, progress and ETA."""

    DEFAULT_CSS = """
    PlanPanel { height: 1fr; }
    PlanPanel #plan-status { height: 2; }
    PlanPanel ProgressBar { height: 1; }
    PlanPanel DataTable { height: 1fr; }
    """

    def __init__(self, steps: Sequence, *, simulated: bool, estimates: Sequence[float] | None = None, **kwargs):
        super().__init__(**kwargs)
        self.steps = tuple(steps)
        self.estimates = step_estimates(self.steps, estimates)
        self.simulated = simulated
        self.plain = ""
        self._shown_states: list[str] = []

    def compose(self) -> ComposeResult:
        yield Label("", id="plan-status")
        yield ProgressBar(total=100.0, show_eta=False, id="plan-progress")
        yield DataTable(id="plan-steps", cursor_type="row", zebra_stripes=True)

    def on_mount(self) -> None:
        self.set_steps(self.steps, self.estimates)

    def set_steps(self, steps: Sequence, estimates: Sequence[float] | None = None) -> None:
        """Show `steps` with `estimates` (s, one per step; default the steps' own)."""
        self.steps = tuple(steps)
        self.estimates = step_estimates(self.steps, estimates)
        table = self.query_one("#plan-steps", DataTable)
        table.clear(columns=True)
        table.add_column("#", key="index")
        table.add_column("unit", key="unit")
        table.add_column("kind", key="kind")
        table.add_column("what", key="what")
        table.add_column("est s", key="est")
        table.add_column("state", key="state")
        for s, estimate_s in zip(self.steps, self.estimates):
            table.add_row(str(s.index + 1), s.unit, s.kind, describe_step(s), f"{estimate_s:.1f}",
                          Text("pending", style="dim"), key=str(s.index))
        self._shown_states = ["pending"] * len(self.steps)

    def restyle(self) -> None:
        """Redraw every step's state at the next `show` (the theme changed)."""
        self._shown_states = [""] * len(self.steps)

    def show(self, snapshot: UiSnapshot) -> None:
        p = progress(snapshot, self.steps, self.estimates)
        clock = " (sim clock)" if self.simulated else ""
        k = snapshot.current_step
        if k is not None and k < len(self.steps):
            step = self.steps[k]
            left = f", {p.step_left_s:.1f} s left" if p.step_left_s is not None else ""
            current = f"step {k + 1}/{len(self.steps)} {step.unit} {step.kind}{left}"
        else:
            current = "no step running"
        status = (f"run {snapshot.run_state_text}  {p.fraction:6.1%}  ETA{clock} {format_hms(p.remaining_s)}\n"
                  f"{current}")
        set_text(self.query_one("#plan-status", Label), status)
        bar = self.query_one("#plan-progress", ProgressBar)
        percent = round(p.fraction * 100.0, 1)
        if bar.progress != percent:
            bar.update(progress=percent)
        table = self.query_one("#plan-steps", DataTable)
        pal = palette(self.app)
        for i, state in enumerate(snapshot.step_states):
            if i < len(self._shown_states) and state != self._shown_states[i]:
                self._shown_states[i] = state
                table.update_cell(str(i), "state", Text(state, style=state_style(state, pal)))
        if k is not None and k < table.row_count and table.cursor_row != k:
            table.move_cursor(row=k)
        counts = {s: snapshot.step_states.count(s) for s in set(snapshot.step_states)}
        self.plain = status + "\n" + ", ".join(f"{n} {s}" for s, n in sorted(counts.items()))


def _c(value, decimals: int = 1) -> str:
    """A temperature (or rate) to `decimals`, '-' when unknown."""
    return "-" if value is None or not math.isfinite(value) else f"{value:.{decimals}f}"


class ChamberPanel(Static):
    """A thermal plan's chamber and soak: which temperature of how many, the chamber air against its
    setpoint (mode, alarms), the IMU's temperature, its rate against the soak criterion and the time it
    has been steady against the time required (the sequencer's own soak checks)."""

    DEFAULT_CSS = "ChamberPanel { height: auto; padding: 0 1; }"

    def __init__(self, steps: Sequence, **kwargs):
        super().__init__(**kwargs)
        self.steps = tuple(steps)
        self.blocks = sorted({s.temperature_index for s in self.steps if s.kind == "set_temperature"})
        self.plain = ""
        self._drawn_with: Palette | None = None
        self.border_title = "Chamber"

    def _block(self, snapshot: UiSnapshot):
        """(the current temperature block, its soak step) by the running step (else the last one started)."""
        k = snapshot.current_step
        if k is None:
            started = [i for i, state in enumerate(snapshot.step_states) if state != "pending"]
            k = started[-1] if started else None
        block = thermal_block(self.steps[k].unit) if k is not None and k < len(self.steps) else None
        soak = next((s for s in self.steps if s.kind == "soak" and s.temperature_index == block), None)
        return block, soak

    def show(self, snapshot: UiSnapshot) -> None:
        pal = palette(self.app)
        block, soak_step = self._block(snapshot)
        setpoint = f" {soak_step.setpoint_c:g} degC" if soak_step is not None else ""
        head = (f"temperature {self.blocks.index(block) + 1}/{len(self.blocks)}{setpoint}" if block in self.blocks
                else f"temperatures: {len(self.blocks)}")
        chamber = snapshot.chamber_state
        lines = [Text(head, style="bold")]
        if chamber is None:
            lines.append(Text("chamber: no reading yet"))
        else:
            lines.append(Text(f"air {_c(chamber.temperature_c)}  set {_c(chamber.setpoint_c)} degC"))
            alarms = chamber.describe_alarms()
            lines.append(Text(f"{'running' if chamber.running else 'stopped'}, "
                              + (f"ALARM: {alarms}" if alarms else "alarms: none"),
                              style=f"bold {pal.error}" if alarms else ""))
        lines.append(Text(f"IMU {_c(snapshot.imu.temperature_c, 2)} degC"))
        soak = snapshot.soak
        if soak_step is not None and soak is not None and soak.get("step_index") == soak_step.index:
            rate, steady = soak.get("rate_c_per_min"), float(soak.get("steady_for_s") or 0.0)
            below = rate is not None and abs(rate) < soak_step.rate_c_per_min
            lines.append(Text(f"rate {_c(rate, 3)} degC/min (< {soak_step.rate_c_per_min:g})",
                              style=pal.ok if below else pal.warn))
            if soak.get("done"):
                lines.append(Text(f"soaked: steady {format_hms(steady)}", style=pal.ok))
            elif not soak.get("chamber_at_setpoint"):
                lines.append(Text("soak: air not at setpoint yet"))
            else:
                lines.append(Text(f"steady {format_hms(steady)} / {format_hms(soak_step.stable_s)}"))
            if snapshot.current_step == soak_step.index and snapshot.current_started_s is not None \
                    and snapshot.run_time_s is not None:
                lines.append(Text(f"soaking {format_hms(snapshot.run_time_s - snapshot.current_started_s)} "
                                  f"(max {format_hms(soak_step.max_soak_s)})"))
        elif soak_step is not None:
            lines.append(Text(f"soak: < {soak_step.rate_c_per_min:g} degC/min for "
                              f"{format_hms(soak_step.stable_s)}"))
        plain = "\n".join(line.plain for line in lines)
        if plain != self.plain or pal is not self._drawn_with:
            self._drawn_with = pal
            self.update(Text("\n").join(lines))
        self.plain = plain


def event_style(kind: str, pal: Palette) -> str:
    return {"fault": f"bold {pal.error}", "warning": pal.warn, "transition": "bold"}.get(kind, "")


def log_time(line: LogLine) -> str:
    """An event log line's time: `+h:mm:ss` since the start of its run (on the run's clock: simulated seconds
    on the simulator), or the local wall-clock time `hh:mm:ss` of a line outside a run (the session's own,
    before, between and after runs). A run's times never go back; no line is timed against a run that
    started after it."""
    if line.run_elapsed_s is not None:
        return "+" + format_hms(line.run_elapsed_s)
    return time.strftime("%H:%M:%S", time.localtime(line.wall_s))


class EventLog(RichLog):
    """The run's events and the UI's own notes, one line each, timed by `log_time`: a run's lines from its
    start (a hardware run's clock is the host's monotonic clock, whose raw value, the machine's uptime,
    means nothing to an operator), the others by the wall clock."""

    DEFAULT_CSS = "EventLog { height: 1fr; }"
    MAX_LINES = 2000

    def __init__(self, **kwargs) -> None:
        super().__init__(max_lines=self.MAX_LINES, wrap=True, markup=False, min_width=20, **kwargs)
        self.seen = 0
        self.plain_lines: list[str] = []
        self._kinds: list[str] = []

    def add(self, lines: Sequence[LogLine], total: int) -> None:
        pal = palette(self.app)
        for line in lines:
            e = line.event
            if isinstance(e, StepStarted):
                continue                 # the plan panel shows the running step
            text = f"[{log_time(line)}] {e.kind}: {e.message}"
            self.plain_lines.append(text)
            self._kinds.append(e.kind)
            self.write(Text(text, style=event_style(e.kind, pal)))
        self.plain_lines = self.plain_lines[-self.MAX_LINES:]
        self._kinds = self._kinds[-self.MAX_LINES:]
        self.seen = total

    def restyle(self) -> None:
        """Write the kept lines again in the current theme's colours."""
        pal = palette(self.app)
        self.clear()
        for kind, line in zip(self._kinds, self.plain_lines):
            self.write(Text(line, style=event_style(kind, pal)))


class ResultsPanel(Vertical):
    """The solved coefficients with 1-sigma uncertainties (and the simulator's truth and the error in sigmas,
    (value - truth) / sigma, when known); their units on a line below; the budget's warnings in the status
    line (the Budget tab, `bench.tui.budget_panel`, has the whole budget)."""

    DEFAULT_CSS = """
    ResultsPanel { height: 1fr; }
    ResultsPanel #results-status { height: auto; width: 1fr; }
    ResultsPanel #results-units { height: auto; width: 1fr; }
    ResultsPanel DataTable { height: 1fr; }
    """

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.result = None
        self.plain = ""

    def compose(self) -> ComposeResult:
        yield Label("no result yet: a finished run is solved from its log", id="results-status")
        yield DataTable(id="results-table", zebra_stripes=True)
        yield Label("", id="results-units")

    def show_result(self, result, text: str = "") -> None:
        if result is self.result and (result is not None or text == self.plain):
            return              # (no result: the text is all there is; an aborted run's came after the start)
        self.result = result
        table = self.query_one("#results-table", DataTable)
        table.clear(columns=True)
        status = self.query_one("#results-status", Label)
        if result is None:
            status.update(text or "no result")
            self.plain = text
            return
        truth = result.sim_truth or {}
        # The units go on one line under the table, not in a column: with the simulator's truth and
        # error/sigma the table then fits the 60 columns the panel has on a 100-column terminal.
        table.add_columns("name", "value", "1-sigma", *(("sim truth", "err/σ") if truth else ()))
        lines = []
        for name, c in result.coefficients.items():
            finite_sigma = c.sigma is not None and math.isfinite(c.sigma) and c.sigma > 0
            sigma = f"{c.sigma:.3g}" if c.sigma is not None and math.isfinite(c.sigma) else "-"
            row = [name, f"{c.value:.8g}", sigma]
            if truth:
                true = truth.get(name)
                row.append(f"{true.value:.8g}" if true is not None else "-")
                row.append(_sigmas((c.value - true.value) / c.sigma) if true is not None and finite_sigma else "-")
            table.add_row(*row)
            lines.append(" ".join(row))
        failures = result.quality.extra.get("failures")     # an older file's entry
        head = text or f"{len(result.coefficients)} coefficients"
        if failures:
            head += f"; quality: {failures}"
        if result.verdict is not None:      # the verdict first: what an operator looks for
            worst = f"; worst: {result.verdict.worst}" if result.verdict.worst else ""
            head = f"VERDICT {stored_headline(result.verdict.to_dict())}{worst}\n{head}"
        warnings = budget_warnings(result)
        if warnings:
            head += "\n" + "; ".join(warnings) + " (Budget tab)"
        status.update(head)
        units = units_line(result.coefficients)
        self.query_one("#results-units", Label).update(Text(units, style="dim"))
        self.plain = "\n".join([head, *lines, units])


def budget_warnings(result) -> list[str]:
    """The budget's warnings in a few words each: the table's part missing, fits with unexplained scatter."""
    u = result.quality.uncertainty
    if u is None:
        return []
    out = [] if u.get("table_included") else ["WARNING: turntable pointing NOT in sigma"]
    if turn_angle_missing(u):
        out.append("turn angle NOT in sigma")
    bad = [f"{c.get('fit')} {c.get('sensor')}" for c in u.get("consistency", [])
           if isinstance(c, dict) and not c.get("consistent", True)]
    if bad:
        out.append(f"UNEXPLAINED SCATTER: {', '.join(bad)}")
    return out


def _sigmas(z: float) -> str:
    """An error in sigmas to a tenth ('+0.0', '-2.3'); beyond +-1000 in powers of ten."""
    return f"{z:+.1f}" if abs(z) < 999.95 else f"{z:+.0e}"


def units_line(coefficients) -> str:
    """The units of `coefficients` by family, one line: 'units: Kg counts/s per deg/s, D0 deg/h, ...'."""
    by_unit: dict[str, list[str]] = {}
    for name, c in coefficients.items():
        families = by_unit.setdefault(c.unit, [])
        if family_of(name) not in families:
            families.append(family_of(name))
    return "units: " + ", ".join(f"{' '.join(families)} {'1 (direction cosines)' if unit == '1' else unit}"
                                 for unit, families in by_unit.items())


def run_is_active(state: RunState) -> bool:
    return state in (RunState.RUNNING, RunState.PAUSED, RunState.ABORTING)
