"""The events, one class per kind: what each logs (`to_dict`) and what a log's object becomes (`from_dict`)."""

from __future__ import annotations

import pytest

from bench.log.events import (
    EVENT_KINDS,
    CounterWindow,
    DwellRecord,
    Event,
    Fault,
    Info,
    OtherEvent,
    RunWarning,
    SoakStatus,
    StepFinished,
    StepSkipped,
    StepStarted,
    Transition,
    TurnRecord,
    finished_observation_steps,
    make_event,
    malformed_observation_steps,
)
from bench.log.json_topics import event_row
from bench.log.recorder import to_json

DWELL = {"kind": "dwell", "unit": "P01", "index": 1, "angles_deg": [0.0, 90.0, 0.0], "dwell_s": 1.0}
TURN = {"kind": "turn", "unit": "R01", "index": 3, "start_deg": [0.0, 0.0, 0.0], "target_deg": [360.0, 0.0, 0.0],
        "frame": "outer", "direction": "ccw", "revolutions": 1}
SOAK = {"kind": "soak", "unit": "T1", "index": 0, "setpoint_c": 40.0}
STATUS = SoakStatus(12.0, 39.9, 0.01, 40.0, True, 60.0, False, "imu_steady")


def _logged(time_s, kind, message, state=None, index=None, unit=None, data=None) -> dict:
    return {"time_s": time_s, "kind": kind, "message": message, "state": state, "step_index": index,
            "step_unit": unit, "data": data or {}}


#: each event as the sequencer (or the TUI) makes it, and the object the log holds for it (as before the classes)
WRITTEN = [
    (Transition(0.0, "run started: 3 steps", state="running", previous="idle"),
     _logged(0.0, "transition", "run started: 3 steps", "running", data={"from": "idle"})),
    (StepStarted(1.0, "P01 dwell", 1, "P01", step=DWELL), _logged(1.0, "step_started", "P01 dwell", None, 1, "P01",
                                                                 {"step": DWELL})),
    (StepSkipped(1.0, "P01 dwell: complete", 1, "P01", step=DWELL),
     _logged(1.0, "step_skipped", "P01 dwell: complete", None, 1, "P01", {"step": DWELL})),
    (StepFinished(2.0, "P01 dwell done in 1.0 s", 1, "P01", step=DWELL, window=CounterWindow(10, 59, 50)),
     _logged(2.0, "step_finished", "P01 dwell done in 1.0 s", None, 1, "P01",
             {"step": DWELL, "counter_first": 10, "counter_last": 59, "samples": 50})),
    (StepFinished(9.0, "T1 soak done", 0, "T1", step=SOAK, soak_s=8.5, soak=STATUS),
     _logged(9.0, "step_finished", "T1 soak done", None, 0, "T1",
             {"step": SOAK, "soak_s": 8.5, **STATUS.as_dict()})),
    (Info(12.0, "soak 40 degC: steady", 0, "T1", soak=STATUS),
     _logged(12.0, "info", "soak 40 degC: steady", None, 0, "T1", {"soak": "imu_steady", **STATUS.as_dict()})),
    (Info(13.0, "chamber: safe", details={"chamber": "made_safe"}),
     _logged(13.0, "info", "chamber: safe", data={"chamber": "made_safe"})),
    (Fault(3.0, "ImuTimeout: no sample", 1, "P01", error="ImuTimeout"),
     _logged(3.0, "fault", "ImuTimeout: no sample", None, 1, "P01", {"error": "ImuTimeout"})),
    (Fault(3.5, "table state unknown", table_state="unknown"),
     _logged(3.5, "fault", "table state unknown", data={"table_state": "unknown"})),
    (RunWarning(4.0, "IMU link: 2 lost", 1, "P01", details={"imu_stats": {"counter_gaps": 2}}),
     _logged(4.0, "warning", "IMU link: 2 lost", None, 1, "P01", {"imu_stats": {"counter_gaps": 2}})),
    (make_event(5.0, "info", "jog", data={"command": "jog", "frame": "inner"}),
     _logged(5.0, "info", "jog", data={"command": "jog", "frame": "inner"})),
]


@pytest.mark.parametrize("event, logged", WRITTEN, ids=[f"{e.kind}-{i}" for i, (e, _) in enumerate(WRITTEN)])
def test_each_kind_logs_the_object_it_always_did_and_reads_back_to_the_same_bytes(event, logged):
    assert to_json(event.to_dict()) == to_json(logged)          # byte for byte, key order included
    again = Event.from_dict(logged)
    assert type(again) is type(event) and to_json(again.to_dict()) == to_json(logged)


def test_every_kind_the_bench_writes_has_its_class_and_another_kind_is_kept_as_logged():
    assert {e.kind for e, _ in WRITTEN} == set(EVENT_KINDS)
    logged = _logged(1.0, "calibration_note", "from another tool", "odd", 2, "X1", {"any": [1, 2]})
    event = Event.from_dict(logged)
    assert isinstance(event, OtherEvent) and event.kind == "calibration_note"
    assert to_json(event.to_dict()) == to_json(logged)


def test_the_typed_fields_are_read_from_the_log():
    started, finished = (Event.from_dict(logged) for _, logged in WRITTEN[1:4:2])
    assert isinstance(finished, StepFinished) and finished.window == CounterWindow(10, 59, 50)
    assert finished.record == DwellRecord((0.0, 90.0, 0.0)) and finished.usable and finished.step_kind == "dwell"
    turn = Event.from_dict(_logged(5.0, "step_finished", "R01 turn done", None, 3, "R01",
                                   {"step": TURN, "counter_first": 60, "counter_last": 99, "samples": 40}))
    assert isinstance(turn, StepFinished)
    assert turn.record == TurnRecord((0.0, 0.0, 0.0), (360.0, 0.0, 0.0), "outer", "ccw", 1)
    assert finished_observation_steps([started, finished, turn]) == {"P01": (started, finished), "R01": (None, turn)}
    info = Event.from_dict(WRITTEN[5][1])
    assert isinstance(info, Info) and info.soak == SoakStatus(12.0, 39.9, 0.01, 40.0, True, 60.0, False, "imu_steady")
    transition = Event.from_dict(WRITTEN[0][1])
    assert isinstance(transition, Transition) and (transition.previous, transition.state) == ("idle", "running")


@pytest.mark.parametrize("field, value", [("state", 1), ("step_unit", ["P01"]), ("step_index", 1.5),
                                          ("step_index", 1 << 63), ("time_s", "soon")])
def test_a_field_of_the_wrong_type_is_no_event(field, value):
    """The reader counts such a message as malformed (damage): `event_row` is None."""
    logged = {**WRITTEN[1][1], field: value}
    with pytest.raises((TypeError, ValueError)):
        Event.from_dict(logged)
    assert event_row(logged) is None


def _finished(unit: str, step, **window) -> Event:
    return make_event(2.0, "step_finished", f"{unit} done", None, 1, unit, {"step": step, **window})


def test_a_malformed_dwell_is_kept_with_its_reason_until_a_well_formed_one_replaces_it():
    window = {"counter_first": 10, "counter_last": 5, "samples": 0}
    bad = _finished("P01", DWELL, **window)
    assert isinstance(bad, StepFinished) and not bad.usable and bad.window is None
    assert malformed_observation_steps([bad]) == {
        "P01": "P01: its step_finished event is malformed (its IMU counter window is not two integers, "
               "first <= last); left out"}
    good = _finished("P01", DWELL, counter_first=5, counter_last=10, samples=6)
    assert malformed_observation_steps([bad, good]) == malformed_observation_steps([good, bad]) == {}
    assert finished_observation_steps([good, bad])["P01"][1] is good
    # not an object: named; a step of another kind with a window, or a dwell without one: no observation, no line
    assert malformed_observation_steps([_finished("P02", "dwell", **window)]) == {
        "P02": "P02: its step_finished event is malformed (its step record is not an object); left out"}
    others = [_finished("T1", SOAK, counter_first=1, counter_last=2), _finished("P03", DWELL)]
    assert malformed_observation_steps(others) == {} and finished_observation_steps(others) == {}
