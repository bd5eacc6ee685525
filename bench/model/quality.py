"""A run's quality failures as values: each a `QualityFailure` with its kind, the line users see (`text`) and
the fields code needs (the dwell or turn it is about), made where the line is made (the extraction, the log's
damage, the IMU link, the solve), so that no code parses a line to learn its kind.

A result file keeps the lines only (`run.quality_failures`, a list of strings); `from_text` gives them their kind
back when a file is read (the one place that reads a line's words).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from enum import StrEnum
from typing import Iterable


class FailureKind(StrEnum):
    """What a quality failure is about."""

    MALFORMED_STEP = "malformed_step"          # a dwell's or turn's step_finished event cannot be used; left out
    NO_SAMPLES = "no_samples"                  # a window without IMU samples; left out
    FLAGGED = "flagged"                        # samples the IMU flagged unusable; left out
    DWELL_LOST_SAMPLES = "dwell_lost_samples"  # a dwell's window lost samples; used (mean over those received)
    TURN_LOST_SAMPLES = "turn_lost_samples"    # a turn's window lost samples; left out (its integral is incomplete)
    LEFT_OUT = "left_out"                      # a unit not solved for another reason (not in the logs, a solve)
    DAMAGE = "damage"                          # damage in a log
    LINK_LOST_SAMPLES = "link_lost_samples"    # the IMU link lost samples (a verification's line)
    OUTLIERS = "outliers"                      # residual outliers beyond the outlier threshold
    BUDGET = "budget"                          # residuals inconsistent with the uncertainty budget
    OTHER = "other"                            # a line of a result file none of the above words (from_text only)


#: the kinds of a dwell's or turn's line saying its window lost samples
WINDOW_LOSS = frozenset({FailureKind.DWELL_LOST_SAMPLES, FailureKind.TURN_LOST_SAMPLES})

#: the words of a dwell's or turn's line when its window lost samples
SAMPLES_LOST_IN_WINDOW = "samples lost in its window"
#: how a verification's notes word samples the IMU link lost; how the outliers' line words them
LOST_SAMPLES_FAILURE, OUTLIERS_FAILURE = "IMU link lost samples", "residual outliers beyond the outlier threshold"
_BUDGET_WORDS = "residuals inconsistent with the uncertainty budget"


@dataclass(frozen=True)
class QualityFailure:
    """One reason a run's result should not be trusted as is: `text` the line users see (and the result file
    holds), `unit` the dwell or turn it is about (None: the run's, or not known)."""

    kind: FailureKind
    text: str
    unit: str | None = None

    @property
    def window_loss(self) -> bool:
        """Whether this is a dwell's or turn's line saying its window lost samples."""
        return self.kind in WINDOW_LOSS

    def prefixed(self, prefix: str) -> QualityFailure:
        """The same failure with its line prefixed by `prefix: ` (a log's path where there are several)."""
        return replace(self, text=f"{prefix}: {self.text}")


def window_loss(unit: str, turn: bool, lost: int, expected: int) -> QualityFailure:
    """A dwell's (used: its mean is over the samples received) or a turn's (left out) line when its window lost
    `lost` of `expected` samples."""
    if turn:
        return QualityFailure(FailureKind.TURN_LOST_SAMPLES, f"{unit} turn: {lost} of {expected} "
                              f"{SAMPLES_LOST_IN_WINDOW}: its integral is incomplete; left out", unit)
    return QualityFailure(FailureKind.DWELL_LOST_SAMPLES, f"{unit} dwell: {lost} of {expected} "
                          f"{SAMPLES_LOST_IN_WINDOW}; mean over the {expected - lost} received", unit)


def link_lost_samples(summary: str) -> QualityFailure:
    """The IMU link's line when it lost samples (`summary`: its statistics in words)."""
    return QualityFailure(FailureKind.LINK_LOST_SAMPLES, f"{LOST_SAMPLES_FAILURE}: {summary}")


def outliers(count: int) -> QualityFailure:
    """The line of a solve with `count` residual outliers."""
    return QualityFailure(FailureKind.OUTLIERS, f"{count} {OUTLIERS_FAILURE}")


def damage(lines: Iterable[str]) -> list[QualityFailure]:
    """The logs' damage lines as failures."""
    return [QualityFailure(FailureKind.DAMAGE, line) for line in lines]


def texts(failures: Iterable[QualityFailure]) -> list[str]:
    """The lines of `failures`, as users see them and result files keep them."""
    return [f.text for f in failures]


_WINDOW_LOSS_LINE = re.compile(r"(?:^|: )(\S+) (dwell|turn): \d+ of \d+ " + SAMPLES_LOST_IN_WINDOW)


def from_text(text: str) -> QualityFailure:
    """A result file's line with its kind (the file keeps the line only): the one place that reads a line's words.
    Only a window loss gets its unit back; a line none of the kinds words (damage, a unit left out for another
    reason) comes back as `OTHER`."""
    found = _WINDOW_LOSS_LINE.search(text)
    if found:
        turn = found.group(2) == "turn"
        return QualityFailure(FailureKind.TURN_LOST_SAMPLES if turn else FailureKind.DWELL_LOST_SAMPLES, text,
                              found.group(1))
    if text.startswith(LOST_SAMPLES_FAILURE):
        return QualityFailure(FailureKind.LINK_LOST_SAMPLES, text)
    if text.endswith(OUTLIERS_FAILURE):
        return QualityFailure(FailureKind.OUTLIERS, text)
    if _BUDGET_WORDS in text:
        return QualityFailure(FailureKind.BUDGET, text)
    for words, kind in (("step_finished event is malformed", FailureKind.MALFORMED_STEP),
                        ("no IMU samples in its window", FailureKind.NO_SAMPLES),
                        ("flagged unusable by the IMU", FailureKind.FLAGGED)):
        if words in text:
            return QualityFailure(kind, text)
    return QualityFailure(FailureKind.OTHER, text)


__all__ = ["FailureKind", "LOST_SAMPLES_FAILURE", "OUTLIERS_FAILURE", "QualityFailure", "SAMPLES_LOST_IN_WINDOW",
           "WINDOW_LOSS", "damage", "from_text", "link_lost_samples", "outliers", "texts", "window_loss"]
