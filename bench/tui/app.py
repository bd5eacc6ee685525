"""The lab-operator TUI: `BenchApp` and the factory `create_app` shared by `bench tui` and the tests.

The app draws from a `UiBuffer` on a timer (`refresh_hz`, 20 by default: under a busy run some
ticks come late, and the panels must still refresh >= 10 times a second) and sends
commands to a `BenchSession`; it holds no bench logic of its own. The emergency stop
is an App-level priority binding, so it works on every screen, dialogs included, and
is handled before any widget sees the key.
"""

from __future__ import annotations

import asyncio
import signal
import sys
import threading
import time
from pathlib import Path
from types import FrameType
from typing import Any, Callable

from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical
from textual.css.query import NoMatches
from textual.widgets import Footer, Header, TabbedContent, TabPane

from bench.config.load import default_sim_config
from bench.finish.units import unit_config
from bench.model.result import CalibrationResult
from bench.plan.steps import CHAMBER_KINDS
from bench.run.runner import compile_from_config
from bench.run.timing import estimates
from bench.tui.budget_panel import BudgetPanel
from bench.tui.buffer import CHANNELS, MEAN_WINDOW_S, STALE_AFTER_S, ImuScales, UiBuffer
from bench.tui.panels import ChamberPanel, EventLog, ImuPanel, PlanPanel, ResultsPanel, TablePanel
from bench.tui.replay_session import ReplaySession, log_units, open_log
from bench.tui.screens import ConfirmScreen, GotoScreen, HelpScreen, RateScreen
from bench.tui.session import OPERATOR_ERRORS, BenchSession, SessionError
from bench.tui.units_panel import UNIT_KEY, UnitsPanel, unit_result_texts
from drivers.turntable import FRAMES

ESTOP_KEY = "f12"
#: the tabs under the table and IMU panels: (key, tab id, title); the footer shows their keys as one group
TABS = (("1", "plan-tab", "Plan"), ("2", "results-tab", "Results"), ("3", "budget-tab", "Budget"))
TAB_KEYS = f"{TABS[0][0]}-{TABS[-1][0]}"
#: The interpreter's thread switch interval while the app runs. The run's threads (sequencer, CAN
#: receiver, recorder; on the simulator a CPU-bound simulated world) hold the GIL for up to the
#: default 5 ms at a time, and one screen refresh needs the GIL many times: at 1 ms the panels keep
#: their refresh rate under a 2 kHz IMU (benchmarks/tui_refresh.py).
SWITCH_INTERVAL_S = 0.001
DARK_THEME, LIGHT_THEME = "textual-dark", "textual-light"
#: The table and IMU panels' least height: the IMU panel's (its head, a row per channel, its legend, the border).
#: The taller of the two sets the row's height; the shorter one is drawn as tall (the replay's table panel has
#: no jog line, and was a line short of the IMU panel).
TOP_PANEL_HEIGHT = 1 + len(CHANNELS) + 1 + 2
#: Signals that end the app at once, without the quit question, as quitting does: the session closes (any run
#: aborted, the table stopped, servos off, the log closed). Ctrl-C in the TUI is a key, not SIGINT.
STOP_SIGNALS: tuple[signal.Signals, ...] = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))

#: The help screen: (key, what it does), one row each; a long text wraps under its own column.
HELP_KEYS: tuple[tuple[str, str], ...] = (
    (ESTOP_KEY.upper(), "EMERGENCY STOP, at once (no question): aborts the run and sends the controller's "
                        "abort (servos off). Works on every screen, dialogs included."),
    ("s", "start the plan (asks first and says what will move); the run's log starts here"),
    ("p", "pause at the next step boundary (the table holds its position)"),
    ("r", "resume a paused run"),
    ("a", "abort the run (asks first; controlled stop, then servos off)"),
    ("g", "go to a position (outer, middle, inner; checked against the limits)"),
    ("v", "rate mode: one frame turns at a set rate (checked against the limits)"),
    ("h", "halt: controlled stop of every axis (servos stay on, holding position)"),
    ("j", "choose the frame the jog keys move (outer, middle, inner)"),
    ("[ ]", "jog the chosen frame by -/+ the jog step (servo must be on)"),
    ("e x", "enable (servos on) / stop and disable (servos off), when no run is active"),
    ("c d", "connect / disconnect the table and IMU"),
    (TAB_KEYS, "show the " + ", ".join(f"{title} ({key})" for key, _, title in TABS[:-1])
     + f" or {TABS[-1][2]} ({TABS[-1][0]}) tab"),
    ("t", "light / dark theme"),
    ("?", "this help (Esc, q or ? closes it)"),
    ("q", "quit (asks first while a run is active: the run is aborted, the table stopped)"),
)
#: the help's row of the unit key, above the theme's, in a run of several IMUs only (one IMU: the help as ever)
UNIT_HELP = (UNIT_KEY, "select the next unit (marked >): the IMU panel, Results and Budget tabs show it")
HELP_NOTE = ("Manual commands are refused while a plan runs; the first manual move (g, v, [ ]) starts a log of "
             "manual moves (<id>-manual.mcap), a plan writes its own. Event times: +h:mm:ss since the run started "
             "(simulated seconds with the simulator), hh:mm:ss local time outside a run. IMU values: 1 s means, "
             f"dimmed when stale (no sample for {STALE_AFTER_S:g} s). Replay mode (bench tui --replay LOG): no "
             "hardware; p / r pause and resume the playback, q quits.")


class BenchApp(App):
    """The operator's screen for one bench session (see the module docstring)."""

    TITLE = "turntable-bench"
    ENABLE_COMMAND_PALETTE = False      # its footer entry would push "quit" off a 100-column footer
    CSS = """
    #top { height: auto; }
    #top > * { border: round $primary; min-height: %d; }
    #table-panel { width: 58; }
    #imu-panel { width: 1fr; }
    #bottom { height: 1fr; }
    #left-tabs { width: 1fr; min-width: 64; }
    #events { width: 1fr; min-width: 34; }
    #left-tabs { border: round $primary; }
    #events { border: round $primary; }
    #chamber-panel { border-bottom: hkey $primary; }
    #units-panel { border-bottom: hkey $primary; }
    """ % TOP_PANEL_HEIGHT
    BINDINGS = [
        Binding(ESTOP_KEY, "estop", "E-STOP", priority=True),
        Binding("s", "start", "start"),
        Binding("p", "pause", "pause"),
        Binding("r", "resume", "resume"),
        Binding("a", "abort", "abort"),
        Binding("g", "goto", "go to"),
        Binding("v", "rate", "rate"),
        Binding("h", "halt", "halt"),
        Binding("j", "jog_frame", "jog axis", show=False),
        Binding("left_square_bracket", "jog(-1)", "jog -", show=False),
        Binding("right_square_bracket", "jog(1)", "jog +", show=False),
        Binding("t", "toggle_theme", "theme", show=False),
        Binding("e", "enable", "enable", show=False),
        Binding("x", "disable", "disable", show=False),
        Binding("c", "connect", "connect", show=False),
        Binding("d", "disconnect", "disconnect", show=False),
        # one footer entry for the three ("1-3 tabs": the footer fills a 100-column terminal), the help lists them
        *(Binding(key, f"show_tab('{tab}')", "tabs" if k == 0 else title, show=k == 0, key_display=TAB_KEYS)
          for k, (key, tab, title) in enumerate(TABS)),
        Binding(UNIT_KEY, "next_unit", "unit"),      # shown only in a run of several IMUs (check_action)
        Binding("question_mark,f1", "help", "help"),
        Binding("q", "quit_app", "quit"),
    ]

    def __init__(self, session: BenchSession | ReplaySession, buffer: UiBuffer, *, steps, limits, scales: ImuScales,
                 simulated: bool, auto_connect: bool = True, refresh_hz: float = 20.0, subtitle: str = "",
                 jog_step_deg: float = 1.0, theme: str = DARK_THEME):
        super().__init__()
        self.theme = theme
        self.session, self.buffer = session, buffer
        self.steps, self.limits, self.scales = tuple(steps), limits, scales
        self.simulated = simulated
        #: a thermal plan: the chamber and soak panel sits above the event log
        self.thermal = any(s.kind in CHAMBER_KINDS for s in self.steps)
        self.auto_connect = auto_connect
        self.refresh_hz = float(refresh_hz)
        self.sub_title = subtitle
        self.refreshes = 0                   # timer ticks drawn (the refresh benchmark reads it)
        self._result_shown: CalibrationResult | None = None
        self._results_key: tuple = ()         # what the Results and Budget tabs show (compared by identity)
        self.unit_index = 0                  # the selected unit (a run of several IMUs)
        self.unit_scales: tuple[ImuScales, ...] = ()   # each unit's, the reference first (set by create_app)
        self.jog_frame = 0                   # the frame [ and ] move
        self.jog_step_deg = float(jog_step_deg)
        self.rate_dps = 0.0                  # the rate dialog's last value
        self.stopped_by: str | None = None   # the stop signal that ended the app (its name), if one did
        self._previous_handlers: dict[int, Callable[[int, FrameType | None], Any] | int] = {}

    def compose(self) -> ComposeResult:
        yield Header(show_clock=False)
        with Horizontal(id="top"):
            yield TablePanel(self.limits, id="table-panel")
            yield ImuPanel(self.scales, id="imu-panel")
        with Horizontal(id="bottom"):
            with TabbedContent(id="left-tabs", initial="plan-tab"):
                with TabPane("Plan", id="plan-tab"):
                    yield PlanPanel(self.steps, simulated=self.simulated, estimates=self.buffer.estimates,
                                    id="plan-panel")
                with TabPane("Results", id="results-tab"):
                    yield ResultsPanel(id="results-panel")
                with TabPane("Budget", id="budget-tab"):
                    yield BudgetPanel(id="budget-panel")
            with Vertical(id="events"):
                if self.thermal:
                    yield ChamberPanel(self.steps, id="chamber-panel")
                if self.several:
                    yield UnitsPanel(id="units-panel")
                yield EventLog(id="event-log")
        yield Footer()

    def on_mount(self) -> None:
        self._install_stop_signals()
        self._switch_interval = sys.getswitchinterval()
        sys.setswitchinterval(min(self._switch_interval, SWITCH_INTERVAL_S))
        self.query_one("#events").border_title = "Events"
        self.query_one("#table-panel").border_title = "Table"
        self.set_interval(1.0 / self.refresh_hz, self.refresh_panels)
        self.theme_changed_signal.subscribe(self, self._theme_changed)
        if isinstance(self.session, ReplaySession):     # its `replaying` is True
            self.session.play()
        elif self.auto_connect:
            self.action_connect()
        self.refresh_panels()

    def _theme_changed(self, _theme) -> None:
        try:
            self.query_one(PlanPanel).restyle()
            self.query_one(EventLog).restyle()
        except NoMatches:
            return
        self.refresh_panels()

    # -- drawing ---------------------------------------------------------------------------
    def refresh_panels(self) -> None:
        """Redraw every panel from one buffer snapshot (the timer calls it)."""
        try:
            self._draw()
        except NoMatches:
            return                  # the screen is being torn down (exit) or replaced
        self.refreshes += 1

    def _draw(self) -> None:
        snap = self.buffer.snapshot()
        jog = "replay, no hardware: p / r pause and resume it" if self.session.replaying else \
            f"jog: {FRAMES[self.jog_frame]} by {self.jog_step_deg:g} deg ([ ]; j: axis)"
        self.query_one(TablePanel).show(snap, self.session.link, self.session.link_detail, jog)
        units = snap.units
        if units:
            k = self.unit_index % len(units)
            unit = units[k]
            self.query_one(ImuPanel).show(snap, unit, f"IMU {unit.serial} {unit.face} ({k + 1}/{len(units)}): "
                                                      f"{MEAN_WINDOW_S:g} s means",
                                          self.unit_scales[k] if k < len(self.unit_scales) else None)
            self.query_one(UnitsPanel).show(snap, k)
        else:
            self.query_one(ImuPanel).show(snap)
        self.query_one(PlanPanel).show(snap)
        if self.thermal:
            self.query_one(ChamberPanel).show(snap)
        log = self.query_one(EventLog)
        if snap.event_count > log.seen:
            # the events and their count in one call: an event added since the snapshot is shown once
            log.add(*self.buffer.lines_since(log.seen))
        if snap.unit_outcomes:
            self._show_unit_results(snap)
        elif snap.result is not self._result_shown or (snap.result is None and snap.outcome_text
                                                       and self._result_shown is None):
            self._show_results(snap.result, snap.outcome_text, "")

    def _show_results(self, result: CalibrationResult | None, text: str, heading: str) -> None:
        """The Results and Budget tabs show `result` (and `text`; `heading`: above the budget); the first result
        brings the Results tab up."""
        first = result is not None and self._result_shown is None
        self._result_shown = result
        self.query_one(ResultsPanel).show_result(result, text)
        self.query_one(BudgetPanel).show_result(result, heading)
        if first:
            self.query_one(TabbedContent).active = "results-tab"

    def _show_unit_results(self, snap) -> None:
        """A run of several IMUs that ended: the selected unit's result and verdict, and every unit's verdict."""
        outcomes = snap.unit_outcomes
        k = self.unit_index % len(outcomes)
        key = (outcomes, k, snap.result)
        if len(self._results_key) == 3 and all(a is b for a, b in zip(key, self._results_key)):
            return
        self._results_key = key
        self._show_results(outcomes[k].result, *unit_result_texts(snap, k))

    def _refuse(self, exc: Exception) -> None:
        self.notify(str(exc), severity="warning")
        self.buffer.note("warning", f"refused: {exc}")

    # -- actions -----------------------------------------------------------------------------
    def action_estop(self) -> None:
        """Emergency stop first, then close any dialog so the operator sees the table."""
        self.session.estop()
        while len(self.screen_stack) > 1:
            self.pop_screen()

    def _hardware(self, what: str) -> bool:
        """False (after saying why) when this session has no hardware for `what` (a replay)."""
        try:
            self.session.require_hardware(what)
        except SessionError as exc:
            self._refuse(exc)
            return False
        return True

    def action_connect(self) -> None:
        if not self._hardware("connect"):
            return
        if self.session.run is not None:
            self._refuse(SessionError("already connected"))
            return
        self.run_worker(self.session.connect, thread=True, exclusive=True, group="connect", exit_on_error=False)

    def action_disconnect(self) -> None:
        try:
            self.session.disconnect()
        except SessionError as exc:
            self._refuse(exc)

    def action_start(self) -> None:
        if not self._hardware("start a plan"):
            return
        if self.session.running:
            self._refuse(SessionError("a run is already active"))
            return
        if not self.session.connected and self.session.run is None:
            self._refuse(SessionError("not connected (press c)"))
            return

        def confirmed(yes: bool | None) -> None:
            if yes:
                try:
                    self.query_one(TabbedContent).active = "plan-tab"
                    self.session.start()
                except OPERATOR_ERRORS as exc:
                    self._refuse(exc)

        self.push_screen(ConfirmScreen("Start the calibration plan?", self.session.describe_plan(),
                                       yes="Start", no="Cancel"), confirmed)

    def _control(self, name: str) -> None:
        try:
            getattr(self.session, name)()
        except SessionError as exc:
            self._refuse(exc)

    def action_pause(self) -> None:
        self._control("pause")

    def action_resume(self) -> None:
        self._control("resume")

    def action_abort(self) -> None:
        """Abort the run after a yes (as `s` asks before starting); F12 is the stop that never asks."""
        if not self._hardware("abort a run"):
            return
        if not self.session.running:
            self._refuse(SessionError("no run is active"))
            return

        def confirmed(yes: bool | None) -> None:
            if yes:
                self._control("abort")

        self.push_screen(ConfirmScreen("Abort the run?", "The table is stopped (controlled stop), then the servos "
                                       "are switched off. The log is kept; the run ends as aborted.",
                                       yes="Abort run", no="Continue"), confirmed)

    def action_enable(self) -> None:
        self._control("enable")

    def action_disable(self) -> None:
        self._control("disable")

    def _manual_ok(self, what: str) -> bool:
        """Manual table commands need the hardware, a connection and no active run."""
        if not self._hardware(what):
            return False
        if self.session.run is None or self.session.running:
            self._refuse(SessionError("not connected" if self.session.run is None else "a run is active"))
            return False
        return True

    def action_goto(self) -> None:
        if not self._manual_ok("go to a position"):
            return
        state = self.buffer.snapshot().table_state
        current = state.angles_deg if state is not None else None

        def chosen(angles) -> None:
            if angles is not None:
                try:
                    self.session.go_to(angles)
                except OPERATOR_ERRORS as exc:   # limits, link: shown to the operator
                    self._refuse(exc)

        self.push_screen(GotoScreen(self.limits, current), chosen)

    def action_rate(self) -> None:
        if not self._manual_ok("set a rate"):
            return

        def chosen(choice) -> None:
            if choice is None:
                return
            try:
                if choice[0] == "stop":
                    self.session.stop_motion()
                else:
                    _, frame, rate = choice
                    self.jog_frame, self.rate_dps = frame, rate
                    self.session.set_rate(frame, rate)
            except OPERATOR_ERRORS as exc:   # limits, link: shown to the operator
                self._refuse(exc)

        self.push_screen(RateScreen(self.limits, self.jog_frame, self.rate_dps), chosen)

    def action_halt(self) -> None:
        if not self._hardware("stop the table"):
            return
        self._control("stop_motion")

    def action_jog_frame(self) -> None:
        self.jog_frame = (self.jog_frame + 1) % 3
        self.refresh_panels()

    def action_jog(self, direction: int) -> None:
        if not self._manual_ok("jog"):
            return
        try:
            self.session.jog(self.jog_frame, direction * self.jog_step_deg)
        except OPERATOR_ERRORS as exc:   # servo off, limits: shown to the operator
            self._refuse(exc)

    def action_show_tab(self, tab: str) -> None:
        self.query_one(TabbedContent).active = tab

    @property
    def several(self) -> bool:
        """A run of several IMUs: the Units panel, the unit key."""
        return len(self.buffer.units) > 1

    def action_next_unit(self) -> None:
        """Select the next unit (a run of several IMUs): the IMU panel, Results and Budget show it."""
        n = len(self.buffer.units)
        if n < 2:
            return                      # (one IMU: the key is off, `check_action`)
        self.unit_index = (self.unit_index + 1) % n
        self.refresh_panels()

    def check_action(self, action: str, parameters: tuple[object, ...]) -> bool | None:
        """The unit key is shown (in the footer) only in a run of several IMUs."""
        if action == "next_unit" and not self.several:
            return False
        return True

    def action_toggle_theme(self) -> None:
        self.theme = LIGHT_THEME if self.current_theme.dark else DARK_THEME

    def action_help(self) -> None:
        keys = HELP_KEYS
        if self.several:        # the unit key's row, and no blank line above the note: it all fits 100x30 still
            theme = next(k for k, (key, _) in enumerate(keys) if key == "t")
            keys = (*keys[:theme], UNIT_HELP, *keys[theme:])
        self.push_screen(HelpScreen(keys, HELP_NOTE, compact=self.several))

    def action_quit_app(self) -> None:
        if not self.session.busy:
            self.exit()
            return

        def confirmed(yes: bool | None) -> None:
            if yes:
                self.exit()

        self.push_screen(ConfirmScreen("Quit?", "A run is active. Quitting aborts it: the table is stopped "
                                       "and the servos switched off.", yes="Abort and quit", no="Stay"), confirmed)

    async def action_quit(self) -> None:
        self.action_quit_app()

    def on_unmount(self) -> None:
        # Whatever ends the app (quit, a stop signal, a test leaving run_test) stops the table and closes the
        # devices; a stop signal meanwhile changes nothing (the loop is busy here), then the handlers go.
        try:
            self.session.close()
        finally:
            sys.setswitchinterval(getattr(self, "_switch_interval", sys.getswitchinterval()))
            self._remove_stop_signals()

    # -- stop signals ----------------------------------------------------------------------------------
    def _install_stop_signals(self) -> None:
        """SIGINT, SIGTERM and SIGHUP end the app (`stop_signal`), through the event loop; only in the main
        thread (where the loop can take signals). An ignored SIGHUP stays ignored (`nohup`)."""
        if threading.current_thread() is not threading.main_thread():
            return
        loop = asyncio.get_running_loop()
        for signum in STOP_SIGNALS:
            if signum == getattr(signal, "SIGHUP", None) and signal.getsignal(signum) is signal.SIG_IGN:
                continue
            previous = signal.getsignal(signum)
            loop.add_signal_handler(signum, self.stop_signal, signum)
            # (None: a handler not installed from Python; the default is the closest to put back)
            self._previous_handlers[signum] = signal.SIG_DFL if previous is None else previous

    def _remove_stop_signals(self) -> None:
        """Put back the handlers `_install_stop_signals` replaced."""
        handlers, self._previous_handlers = self._previous_handlers, {}
        if not handlers:
            return
        loop = asyncio.get_running_loop()
        for signum, previous in handlers.items():
            loop.remove_signal_handler(signum)
            signal.signal(signum, previous)

    def stop_signal(self, signum: int) -> None:
        """A stop signal: quit at once (no question); unmounting aborts any run and stops the table."""
        if self.stopped_by is None:
            self.stopped_by = signal.Signals(signum).name
            self.buffer.note("warning", f"{self.stopped_by}: quitting; any run is aborted and the table stopped")
        self.exit()


#: the footer's keys that command hardware: a replay hides them (pressed anyway, they say "replay mode: no hardware")
HARDWARE_ACTIONS = ("estop", "start", "abort", "goto", "rate", "halt")


class ReplayApp(BenchApp):
    """The app on a replay session: the same screen, with only the playback's keys in the footer."""

    BINDINGS = [Binding(b.key, b.action, b.description, show=False, priority=b.priority)
                for b in BenchApp.BINDINGS if isinstance(b, Binding) and b.action in HARDWARE_ACTIONS]


def create_app(*, config=None, sim: bool = False, replay: str | Path | None = None, speed: float | None = 1.0,
               out_dir: str | Path | None = None, operator: str = "", auto_connect: bool = True,
               refresh_hz: float = 20.0, poll_s: float = 0.1, jog_step_deg: float = 1.0,
               theme: str = DARK_THEME, clock: Callable[[], float] = time.monotonic,
               wall_clock: Callable[[], float] = time.time) -> BenchApp:
    """The TUI for `config` (the built-in simulated bench when None and `sim`), or for the replay of
    the run log `replay` at `speed` times real time (None: as fast as possible; no hardware).

    `out_dir`: where logs and results go (default the config's output folder);
    `auto_connect`: open the devices when the app starts; `refresh_hz`: panel redraws
    per second; `poll_s`: the idle monitor's period; `jog_step_deg`: what [ and ] move; `clock` (monotonic)
    and `wall_clock` (`time.time`): the session's clocks, for how old the IMU values are and the event log's
    times outside a run (tests inject them). A log that cannot be read raises `bench.log.reader.LogError`.
    """
    if replay is not None:
        return _create_replay_app(replay, speed, UiBuffer((), clock=clock, wall_clock=wall_clock),
                                  refresh_hz=refresh_hz, jog_step_deg=jog_step_deg, theme=theme)
    if config is None:
        if not sim:
            raise ValueError("say config=..., sim=True or replay=LOG")
        config = default_sim_config()
    sim = sim or config.table.is_sim
    plan = compile_from_config(config)
    # the plan is the same whoever runs it; the progress goes by what it will take on this bench (the simulator's
    # own timing under sim)
    buffer = UiBuffer(plan.steps, clock=clock, wall_clock=wall_clock, estimates=estimates(config, plan.steps, sim))
    session = BenchSession(config, plan, sim=sim, out_dir=out_dir if out_dir is not None else config.output.folder,
                           buffer=buffer, operator=operator, poll_s=poll_s)
    names = " + ".join(s.name for s in (config.plan.positions, config.plan.rotations) if s is not None)
    app = BenchApp(session, buffer, steps=plan.steps, limits=config.table.limits,
                   scales=ImuScales.from_config(config, sim), simulated=sim, auto_connect=auto_connect,
                   refresh_hz=refresh_hz, subtitle=f"{'simulator' if sim else config.table.url} - {names}",
                   jog_step_deg=jog_step_deg, theme=theme)
    _set_units(app, config, sim, [(unit.identity.serial, unit.mounting_name) for unit in config.units])
    return app


def _set_units(app: BenchApp, config, sim: bool, units: list[tuple[str, str]]) -> None:
    """A run of several IMUs: its units (serial, mounting face) in the buffer, each unit's scales in the app."""
    if len(units) < 2:
        return
    app.buffer.set_units(units)
    app.unit_scales = tuple(ImuScales.from_config(unit_config(config, k), sim) for k in range(len(units)))


def _create_replay_app(path, speed, buffer: UiBuffer, **kwargs) -> BenchApp:
    opened = open_log(path)
    buffer.begin_run(opened.steps)
    session = ReplaySession(opened, buffer=buffer, speed=speed)
    app = ReplayApp(session, buffer, steps=opened.steps, limits=opened.limits,
                    scales=ImuScales.from_config(opened.config, opened.simulated), simulated=opened.simulated,
                    auto_connect=False, subtitle=f"replay of {opened.path.name}", **kwargs)   # (the pace: link line)
    _set_units(app, opened.config, opened.simulated, log_units(opened))
    return app
