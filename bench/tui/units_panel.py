"""The units of a run of several IMUs (`[[imu]]`), two lines each: its serial, mounting face, samples and lost
samples, and under them its state (receiving, waiting, stale, or dropped with the reason); the selected unit (the
IMU panel's and the result tabs' unit; `u` cycles it) marked `>`. Only a run of several units has this panel."""

from __future__ import annotations

from rich.text import Text
from textual.widgets import Static

from bench.tui.buffer import UiSnapshot
from bench.tui.panels import palette
from bench.tui.tracks import units_summary

#: the key that cycles the selected unit
UNIT_KEY = "u"


class UnitsPanel(Static):
    """Every unit, two lines each: serial, face, samples and lost samples; its state under them (a dropped unit's
    reason wraps); `plain` keeps what it drew."""

    DEFAULT_CSS = "UnitsPanel { height: auto; padding: 0 1; }"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.plain = ""
        self._drawn_with = None

    def show(self, snapshot: UiSnapshot, selected: int) -> None:
        pal = palette(self.app)
        width = max((len(u.serial) for u in snapshot.units), default=0)
        face_width = max((len(u.face) for u in snapshot.units), default=0)
        lines = []
        for k, unit in enumerate(snapshot.units):
            state = unit.state
            style = (f"bold {pal.error}" if unit.dropped else pal.warn if unit.imu.stale or unit.imu.age_s is None
                     else pal.ok)
            head = (f"{'>' if k == selected else ' '} {unit.serial:<{width}} {unit.face:<{face_width}} "
                    f"{unit.imu.samples:>8} lost {unit.imu.lost_samples}")
            # the state on a line of its own: at 100 columns the panel has 32, and a reason is longer
            lines.append(Text.assemble((head, "bold" if k == selected else ""), "\n    ", (state, style)))
        plain = "\n".join(line.plain for line in lines)
        if plain != self.plain or pal is not self._drawn_with:
            self._drawn_with = pal
            self.update(Text("\n").join(lines))
        self.plain = plain


def unit_result_texts(snapshot: UiSnapshot, k: int) -> tuple[str, str]:
    """(the Results tab's status, the Budget tab's heading) of unit `k`'s outcome: which unit, its result or why it
    has none, and every unit's verdict on one line."""
    outcomes = snapshot.unit_outcomes
    chosen = outcomes[k]
    face = next((u.face for u in snapshot.units if u.serial == chosen.serial), "")
    unit = f"unit {chosen.serial}{' (' + face + ')' if face else ''} ({k + 1}/{len(outcomes)})"
    summary = units_summary(outcomes)
    account = chosen.text if chosen.result is not None else f"no result: {chosen.text}"
    return f"{unit}: {account}\n{summary}", f"{unit}\n{summary}"


__all__ = ["UNIT_KEY", "UnitsPanel", "unit_result_texts"]
