"""Dialogs: confirmations, go to position and rate mode (validated against the limits), help."""

from __future__ import annotations

from typing import Sequence

from rich.table import Table as RichTable
from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical
from textual.screen import ModalScreen
from textual.widgets import Button, Input, Label, Select, Static

from bench.model.kinematics import triple
from bench.tui.session import check_rate_command
from drivers.errors import DeviceLimitError
from drivers.turntable import FRAMES

DIALOG_CSS = """
{name} {{ align: center middle; }}
{name} > Vertical {{ width: 76; height: auto; max-height: 90%; border: thick $accent; background: $surface;
                      padding: 1 2; }}
{name} .buttons {{ height: auto; margin-top: 1; align-horizontal: right; }}
{name} Button {{ margin-left: 2; }}
{name} .error {{ color: $error; height: auto; }}
"""


class ConfirmScreen(ModalScreen[bool]):
    """Yes/no with a title and a description; dismisses with True only on "yes". A line under the buttons says
    the keys: y for yes, n or Esc for no, Enter for the highlighted button (no at first: a stray Enter is safe)."""

    DEFAULT_CSS = DIALOG_CSS.format(name="ConfirmScreen") + """
    ConfirmScreen #confirm-keys { margin-top: 1; color: $text-muted; }
    """
    BINDINGS = [Binding("escape", "cancel", "cancel"), Binding("y", "confirm", "yes"), Binding("n", "cancel", "no")]
    AUTO_FOCUS = "#no"      # a stray Enter must not start anything

    def __init__(self, title: str, body: str, yes: str = "Yes", no: str = "No", **kwargs):
        super().__init__(**kwargs)
        self.title_text, self.body, self.yes, self.no = title, body, yes, no

    def compose(self) -> ComposeResult:
        with Vertical():
            yield Label(self.title_text, classes="title")
            yield Static(self.body, id="confirm-body")
            with Horizontal(classes="buttons"):
                yield Button(self.no, id="no")
                yield Button(self.yes, id="yes", variant="warning")
            yield Label(self.keys_text(self.no), id="confirm-keys")

    def keys_text(self, highlighted: str) -> str:
        return f"y: {self.yes}   n or Esc: {self.no}   Enter: the highlighted button ({highlighted})"

    def on_descendant_focus(self, event) -> None:
        if isinstance(event.widget, Button):
            self.query_one("#confirm-keys", Label).update(self.keys_text(str(event.widget.label)))

    def on_button_pressed(self, event: Button.Pressed) -> None:
        self.dismiss(event.button.id == "yes")

    def action_confirm(self) -> None:
        self.dismiss(True)

    def action_cancel(self) -> None:
        self.dismiss(False)


class GotoScreen(ModalScreen["tuple[float, float, float] | None"]):
    """Three angles (outer, middle, inner, deg), each a number within its axis's limits."""

    DEFAULT_CSS = DIALOG_CSS.format(name="GotoScreen") + """
    GotoScreen Input { width: 24; }
    GotoScreen .axis { height: auto; }
    GotoScreen .axis Label { width: 10; padding-top: 1; }
    """
    BINDINGS = [Binding("escape", "cancel", "cancel")]
    AUTO_FOCUS = "#goto-outer"

    def __init__(self, limits, current_deg=None, **kwargs):
        super().__init__(**kwargs)
        self.limits = limits
        self.current_deg = current_deg or (0.0, 0.0, 0.0)

    def compose(self) -> ComposeResult:
        with Vertical():
            yield Label("Go to position (deg). The table is enabled (servos on) and moves.")
            for k, name in enumerate(FRAMES):
                with Horizontal(classes="axis"):
                    yield Label(name)
                    yield Input(f"{self.current_deg[k]:g}", id=f"goto-{name}")
            yield Label("", id="goto-error", classes="error")
            with Horizontal(classes="buttons"):
                yield Button("Cancel", id="cancel")
                yield Button("Move", id="move", variant="warning")

    def validate(self) -> tuple[float, float, float] | None:
        """The three angles, or None after showing what is wrong."""
        angles = []
        error = self.query_one("#goto-error", Label)
        for k, name in enumerate(FRAMES):
            text = self.query_one(f"#goto-{name}", Input).value.strip()
            try:
                value = float(text)
            except ValueError:
                error.update(f"{name}: {text!r} is not a number")
                return None
            try:
                self.limits.check_position(k, value)
            except DeviceLimitError as exc:
                error.update(str(exc))
                return None
            angles.append(value)
        error.update("")
        return triple(angles)

    def on_input_submitted(self, event: Input.Submitted) -> None:
        self._move()

    def on_button_pressed(self, event: Button.Pressed) -> None:
        if event.button.id == "move":
            self._move()
        else:
            self.dismiss(None)

    def _move(self) -> None:
        angles = self.validate()
        if angles is not None:
            self.dismiss(angles)

    def action_cancel(self) -> None:
        self.dismiss(None)


class RateScreen(ModalScreen["tuple | None"]):
    """Rate mode on one frame: dismisses with ("rate", frame index, deg/s) once the rate passes the
    limits (`check_rate_command`), ("stop",) for a controlled stop of every axis, None to cancel."""

    DEFAULT_CSS = DIALOG_CSS.format(name="RateScreen") + """
    RateScreen Input { width: 24; }
    RateScreen Select { width: 24; }
    RateScreen .axis { height: auto; }
    RateScreen .axis Label { width: 12; padding-top: 1; }
    """
    BINDINGS = [Binding("escape", "cancel", "cancel")]
    AUTO_FOCUS = "#rate-value"

    def __init__(self, limits, frame: int = 0, rate_dps: float = 0.0, **kwargs):
        super().__init__(**kwargs)
        self.limits, self.frame, self.rate_dps = limits, int(frame), float(rate_dps)

    def compose(self) -> ComposeResult:
        with Vertical():
            yield Label("Rate mode: the frame's servo is switched on and it turns until stopped (h or Stop).")
            with Horizontal(classes="axis"):
                yield Label("frame")
                yield Select([(name, k) for k, name in enumerate(FRAMES)], value=self.frame, allow_blank=False,
                             id="rate-frame")
            with Horizontal(classes="axis"):
                yield Label("rate deg/s")
                yield Input(f"{self.rate_dps:g}", id="rate-value")
            yield Label("limits: " + ", ".join(f"{name} {a.max_rate_dps:g} deg/s"
                                               for name, a in zip(FRAMES, self.limits.axes)), id="rate-limits")
            yield Label("", id="rate-error", classes="error")
            with Horizontal(classes="buttons"):
                yield Button("Cancel", id="cancel")
                yield Button("Stop all", id="stop", variant="primary")
                yield Button("Set rate", id="set", variant="warning")

    def validate(self) -> tuple | None:
        """("rate", frame, deg/s), or None after showing what is wrong."""
        error = self.query_one("#rate-error", Label)
        select: Select[int] = self.query_one("#rate-frame", Select)
        frame = select.selection        # never blank: the select has allow_blank=False
        if frame is None:
            error.update("choose a frame")
            return None
        text = self.query_one("#rate-value", Input).value.strip()
        try:
            rate = float(text)
        except ValueError:
            error.update(f"rate: {text!r} is not a number")
            return None
        try:
            check_rate_command(self.limits, frame, rate)
        except DeviceLimitError as exc:
            error.update(str(exc))
            return None
        error.update("")
        return ("rate", frame, rate)

    def on_input_submitted(self, event: Input.Submitted) -> None:
        self._set()

    def on_button_pressed(self, event: Button.Pressed) -> None:
        if event.button.id == "set":
            self._set()
        elif event.button.id == "stop":
            self.dismiss(("stop",))
        else:
            self.dismiss(None)

    def _set(self) -> None:
        chosen = self.validate()
        if chosen is not None:
            self.dismiss(chosen)

    def action_cancel(self) -> None:
        self.dismiss(None)


class HelpScreen(ModalScreen[None]):
    """The key bindings and what they do: a key column and a description column that wraps under itself,
    in a dialog as wide as a 100-column terminal allows (Esc, q, ? or F1 closes it)."""

    DEFAULT_CSS = DIALOG_CSS.format(name="HelpScreen") + """
    HelpScreen > Vertical { width: 96; max-width: 100%; padding: 0 1; }
    HelpScreen #help-title { margin-bottom: 1; }
    HelpScreen #help-note { margin-top: 1; }
    HelpScreen.-compact #help-note { margin-top: 0; }
    """
    BINDINGS = [Binding("escape,q,question_mark,f1", "close", "close")]

    def __init__(self, keys: Sequence[tuple[str, str]], note: str = "", compact: bool = False, **kwargs):
        super().__init__(**kwargs)
        self.keys, self.note = tuple(keys), note
        # `compact`: no blank line above the note (a row more of keys still fits 30 lines)
        self.set_class(compact, "-compact")

    def compose(self) -> ComposeResult:
        grid = RichTable.grid(padding=(0, 2))
        grid.add_column("key", no_wrap=True, style="bold")
        grid.add_column("what", ratio=1)
        for key, what in self.keys:
            grid.add_row(key, what)
        with Vertical():
            yield Label(Text.assemble(("turntable-bench operator keys", "bold"), "   (Esc, q or ? closes)"),
                        id="help-title")
            yield Static(grid, id="help-text")
            if self.note:
                yield Static(self.note, id="help-note")

    def action_close(self) -> None:
        self.dismiss(None)
