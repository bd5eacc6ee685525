"""The shipped Foxglove Studio layout (foxglove/turntable-bench.layout.json) fits the logs the recorder writes.

Checks the layout's structure (Foxglove's export format: `configById` + a mosaic tree
in `layout`, every leaf configured and every config placed), that every topic it
names is one the recorder writes with the schema the panel expects, and that every
message path resolves to a number in real messages written by `McapRecorder`.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from bench.log.events import make_event
from bench.log.format import CHANNELS, SCHEMAS, TF_FRAMES, TOPIC_EVENTS, TOPIC_LOG, TOPIC_TF
from bench.log.recorder import McapRecorder
from drivers.imu import ImuSampleBlock
from drivers.turntable import AxisMode, AxisState, AxisStatus, TableState

LAYOUT = Path(__file__).resolve().parents[3] / "foxglove" / "turntable-bench.layout.json"
PANEL_TYPES = {"Plot", "3D", "RosOut", "RawMessages"}
#: Foxglove message path: /topic.field or /topic.field[index] (all the layout needs).
PATH = re.compile(r"^(?P<topic>/[A-Za-z0-9_/]+)\.(?P<field>[A-Za-z_][A-Za-z0-9_]*)(?:\[(?P<index>\d+)\])?$")


@pytest.fixture(scope="module")
def layout() -> dict:
    return json.loads(LAYOUT.read_text(encoding="utf-8"))


def leaves(node, where="layout") -> list[str]:
    """Panel ids of a mosaic tree; fails on a malformed node."""
    if isinstance(node, str):
        return [node]
    assert isinstance(node, dict), f"{where}: a mosaic node is a panel id or a split, got {node!r}"
    assert set(node) <= {"first", "second", "direction", "splitPercentage"}, f"{where}: {sorted(node)}"
    assert node.get("direction") in ("row", "column"), f"{where}: direction {node.get('direction')!r}"
    if "splitPercentage" in node:
        assert 0 < node["splitPercentage"] < 100, f"{where}: splitPercentage {node['splitPercentage']}"
    return leaves(node["first"], where + ".first") + leaves(node["second"], where + ".second")


def message_paths(layout: dict) -> list[str]:
    out = []
    for panel_id, config in layout["configById"].items():
        if panel_id.startswith("Plot!"):
            out += [p["value"] for p in config["paths"]]
    return out


def schema_of(topic: str) -> dict:
    assert topic in CHANNELS, f"{topic} is not a topic the recorder writes ({sorted(CHANNELS)})"
    return SCHEMAS[CHANNELS[topic][0]]


# -- structure ---------------------------------------------------------------------------------

def test_layout_has_the_foxglove_export_shape(layout):
    assert {"configById", "globalVariables", "userNodes", "layout"} <= set(layout)
    assert layout["globalVariables"] == {} and layout["userNodes"] == {}
    ids = leaves(layout["layout"])
    assert len(ids) == len(set(ids)), "a panel appears twice in the layout tree"
    assert set(ids) == set(layout["configById"]), "every placed panel needs a config and every config a place"
    for panel_id in ids:
        kind, _, suffix = panel_id.partition("!")
        assert kind in PANEL_TYPES and suffix, panel_id


def test_every_message_path_names_a_recorded_numeric_field(layout):
    paths = message_paths(layout)
    assert paths
    for path in paths:
        m = PATH.match(path)
        assert m, f"{path!r} is not a /topic.field[index] message path"
        fields = schema_of(m["topic"])["properties"]
        assert m["field"] in fields, f"{path}: {m['field']!r} is not a field of {m['topic']} ({sorted(fields)})"
        spec = fields[m["field"]]
        if m["index"] is not None:
            assert spec["type"] == "array" and spec["items"]["type"] == "number", path
            assert int(m["index"]) < spec["maxItems"], path
        else:
            assert spec["type"] == "number", path


def test_plots_show_every_gyro_and_accelerometer_channel_and_the_table_angles(layout):
    paths = set(message_paths(layout))
    for field in ("gyro_rate", "acc_rate"):
        assert {f"/imu/samples.{field}[{i}]" for i in range(3)} <= paths
    assert {f"/table/state.angles_deg[{i}]" for i in range(3)} <= paths
    for panel_id, config in layout["configById"].items():
        if panel_id.startswith("Plot!"):
            assert all(p["timestampMethod"] == "receiveTime" and p["enabled"] for p in config["paths"]), panel_id


def test_log_events_and_3d_panels_use_the_recorders_topics(layout):
    configs = layout["configById"]
    logs = [c for k, c in configs.items() if k.startswith("RosOut!")]
    assert [c["topicToRender"] for c in logs] == [TOPIC_LOG]
    assert CHANNELS[TOPIC_LOG][0] == "foxglove.Log"
    raw = [c for k, c in configs.items() if k.startswith("RawMessages!")]
    assert [c["topicPath"] for c in raw] == [TOPIC_EVENTS]
    (three_d,) = [c for k, c in configs.items() if k.startswith("3D!")]
    assert three_d["followTf"] in TF_FRAMES
    assert set(three_d["topics"]) == {TOPIC_TF} and CHANNELS[TOPIC_TF][0] == "foxglove.FrameTransform"
    assert {k.removeprefix("frame:") for k in three_d["transforms"]} == set(TF_FRAMES)


# -- against real recorded messages ---------------------------------------------------------------

def resolve(message: dict, path: str):
    m = PATH.match(path)
    value = message[m["field"]]
    return value[int(m["index"])] if m["index"] is not None else value


def test_message_paths_resolve_to_numbers_in_a_recorded_log(layout, tmp_path):
    log = tmp_path / "small.mcap"
    axes = tuple(AxisState(a, 0.5, AxisMode.POSITION, AxisStatus.ENABLED | AxisStatus.IN_POSITION)
                 for a in (10.0, 20.0, 30.0))
    block = ImuSampleBlock(np.arange(5, dtype=np.int64), np.linspace(0.0, 0.04, 5), np.full((5, 3), 0.25),
                           np.full((5, 3), 40.0), np.full(5, 25.0), np.zeros(5, np.int64), 100.0)
    with McapRecorder(str(log)) as recorder:
        recorder.on_event(make_event(0.0, "transition", "run started", "running", data={"from": "idle"}))
        recorder.on_table_state(TableState(0.01, axes))
        recorder.on_imu(block)
    by_topic: dict[str, list[dict]] = {}
    with open(log, "rb") as f:
        for _schema, channel, message in make_reader(f).iter_messages():
            if channel.message_encoding == "json":
                by_topic.setdefault(channel.topic, []).append(json.loads(message.data))
    for path in message_paths(layout):
        topic = PATH.match(path)["topic"]
        assert by_topic.get(topic), f"no {topic} message recorded"
        values = [resolve(msg, path) for msg in by_topic[topic]]
        assert all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values), (path, values)
    assert resolve(by_topic["/table/state"][0], "/table/state.angles_deg[2]") == 30.0
    assert resolve(by_topic["/imu/samples"][0], "/imu/samples.gyro_rate[0]") == 25.0
    frames = {(m["parent_frame_id"], m["child_frame_id"]) for m in by_topic[TOPIC_TF]}
    assert frames == set(zip(TF_FRAMES, TF_FRAMES[1:]))
    assert by_topic[TOPIC_LOG] and by_topic[TOPIC_EVENTS]
