"""Quality failures are values (`QualityFailure`): made with their kind where their lines are made, judged by kind
(never by their words), kept in result files as their lines, and given their kind back when an old file is read
(issue 28 item 3)."""

from __future__ import annotations

import json

import numpy as np

from bench.acceptance.limits import AcceptanceLimits
from bench.acceptance.quality import judged_failures, window_loss_failures
from bench.log.events import make_event
from bench.model.earth import Site
from bench.model.quality import (
    FailureKind,
    QualityFailure,
    damage,
    from_text,
    link_lost_samples,
    outliers,
    texts,
    window_loss,
)
from bench.model.run_section import RunInfo
from bench.solve.extract import extract_observations

K = FailureKind


def _finished(unit: str, index: int, step: dict, first: int, last: int, **extra):
    data = {"step": step, "counter_first": first, "counter_last": last, **extra}
    return make_event(float(index), "step_finished", f"{unit} done", step_index=index, step_unit=unit, data=data)


def _turn() -> dict:
    return {"kind": "turn", "start_deg": [0, 0, 0], "target_deg": [360, 0, 0], "frame": "outer",
            "direction": "ccw", "revolutions": 1}


def test_the_extraction_makes_each_line_with_its_kind_and_unit():
    """A dwell and a turn whose windows lost samples, a window without samples, samples the IMU flagged and a
    malformed step: each line comes with its kind and its unit, and its words are the ones users always saw."""
    dwell = {"kind": "dwell", "angles_deg": [0, 0, 0]}
    events = [_finished("P01", 0, dwell, 0, 99),           # counters 0..99: 40..43 lost
              _finished("P02", 1, dwell, 200, 299),        # nothing received
              _finished("P03", 2, dwell, 300, 309),        # flagged by the IMU
              _finished("R01", 3, _turn(), 400, 499),      # 450 lost
              _finished("P04", 4, {"kind": "dwell", "angles_deg": [0, 0]}, 500, 509)]
    counter = np.array([c for c in range(0, 100) if not 40 <= c < 44] + list(range(300, 310))
                       + [c for c in range(400, 500) if c != 450])
    n = len(counter)
    status = np.zeros(n, dtype=np.int64)
    status[np.searchsorted(counter, 305)] = 1
    out = extract_observations(events, counter, np.zeros((n, 3)), np.zeros((n, 3)), 100.0, Site(),
                               np.array([0.0]), np.zeros((1, 3)), status=status, status_invalid=1)
    by_unit = {p.unit: p for p in out.problems}
    assert by_unit["P04"].kind is K.MALFORMED_STEP
    assert by_unit["P04"].text.startswith("P04: its step_finished event is malformed")
    assert by_unit["P01"] == QualityFailure(
        K.DWELL_LOST_SAMPLES, "P01 dwell: 4 of 100 samples lost in its window; mean over the 96 received", "P01")
    assert by_unit["P02"] == QualityFailure(
        K.NO_SAMPLES, "P02: no IMU samples in its window (counters 200..299); left out", "P02")
    assert by_unit["P03"].kind is K.FLAGGED and "1 of 10 samples flagged unusable by the IMU" in by_unit["P03"].text
    assert by_unit["R01"] == QualityFailure(
        K.TURN_LOST_SAMPLES, "R01 turn: 1 of 100 samples lost in its window: its integral is incomplete; left out",
        "R01")
    assert [p.unit for p in window_loss_failures(out.problems)] == ["P01", "R01"]


def test_judging_goes_by_kind_not_by_words():
    """`max_lost_samples` takes over the link's and a dwell's lost samples, never a turn's (left out) nor a line
    that merely words lost samples; `max_residual_sigma` takes over the outliers."""
    dwell, turn = window_loss("P07", False, 6, 150), window_loss("R02", True, 1, 300)
    link, found = link_lost_samples("7 lost"), outliers(3)
    lookalike = QualityFailure(K.LEFT_OUT, "P09: left out: 2 of 9 samples lost in its window; mean over the", "P09")
    failures = [dwell, turn, link, found, lookalike, *damage(["r.mcap: a chunk's CRC does not match"])]
    assert judged_failures(failures, AcceptanceLimits()) == failures
    lost_judged = judged_failures(failures, AcceptanceLimits(max_lost_samples=10))
    assert [f.kind for f in lost_judged] == [K.TURN_LOST_SAMPLES, K.OUTLIERS, K.LEFT_OUT, K.DAMAGE]
    assert judged_failures(failures, AcceptanceLimits(max_residual_sigma=4.0)) == [
        f for f in failures if f is not found]


def test_a_prefixed_line_keeps_its_kind_and_unit():
    failure = window_loss("T1-P07", False, 2, 40).prefixed("/runs/r.mcap")
    assert failure.text == "/runs/r.mcap: T1-P07 dwell: 2 of 40 samples lost in its window; mean over the 38 received"
    assert (failure.kind, failure.unit, failure.window_loss) == (K.DWELL_LOST_SAMPLES, "T1-P07", True)


def test_result_files_keep_the_lines_and_give_the_kinds_back():
    """The run section's JSON is the list of lines (byte-identical to the strings it always held); reading it
    gives every kind that its words tell back, once, in `from_text`."""
    failures = [window_loss("P01", False, 4, 100).prefixed("/runs/r.mcap"), window_loss("R01", True, 1, 100),
                link_lost_samples("3 lost"), outliers(2),
                QualityFailure(K.BUDGET, "position gyro: residuals inconsistent with the uncertainty budget "
                                         "(chi2/dof 3.1 on 20 dof, p = 1e-06), driven by P07 (+5.2)"),
                QualityFailure(K.MALFORMED_STEP, "P04: its step_finished event is malformed (its revolutions are "
                                                 "not a positive integer); left out"),
                QualityFailure(K.NO_SAMPLES, "P02: no IMU samples in its window (counters 200..299); left out"),
                QualityFailure(K.FLAGGED, "P03: 1 of 10 samples flagged unusable by the IMU (fault); left out")]
    info = RunInfo(run_id="r", mode="simulator", operator="o", software_version="1", state="done", log="r.mcap",
                   logs=["r.mcap"], positions="p", rotations="r", imu={}, site={}, quality_failures=failures,
                   imu_link={}, lost_samples={})
    section = info.to_dict()
    assert section["quality_failures"] == texts(failures)
    assert json.dumps(section["quality_failures"]) == json.dumps([f.text for f in failures])
    back = RunInfo.from_dict(json.loads(json.dumps(section)))
    kinds_known_by_words = [f if f.window_loss else QualityFailure(f.kind, f.text) for f in failures]
    assert back.quality_failures == kinds_known_by_words
    assert back.to_dict() == section


def test_an_old_files_line_of_no_known_words_is_other():
    assert from_text("/runs/r.mcap: the log's summary is missing") == QualityFailure(
        K.OTHER, "/runs/r.mcap: the log's summary is missing")
    assert from_text("P07: left out: not run").kind is K.OTHER
