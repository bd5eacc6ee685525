"""Run logs conform to the MCAP spec as the reference CLI checks it (issue 14, item 6).

The checks `mcap doctor` makes that our logs once failed are repeated here in Python, so the
suite needs no Go tool; with `MCAP_CLI=/path/to/mcap` (built from foxglove/mcap, tag
releases/mcap-cli/v0.0.62) the real `mcap doctor` runs as well.
"""

from __future__ import annotations

import os
import subprocess

import pytest
from mcap.reader import make_reader

from bench.log.format import CAN_ENCODING, CAN_SCHEMA_NAME, TOPIC_CAN, TOPIC_SAMPLES
from tests.helpers.mcap_order import log_time_order


@pytest.fixture(scope="module")
def run_log(short_run):
    return short_run.log, short_run.finished_s


def test_every_schema_with_data_names_its_encoding(run_log):
    """The /can/raw schema had an empty encoding and 608 bytes of data: an error for `mcap doctor`."""
    with open(run_log[0], "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    for schema in summary.schemas.values():
        assert schema.encoding or not schema.data, schema.name
    can_schema = next(s for s in summary.schemas.values() if s.name == CAN_SCHEMA_NAME)
    assert can_schema.encoding == CAN_ENCODING


def test_metadata_holds_no_none_and_attachments_carry_times(run_log):
    path, last_event_s = run_log
    with open(path, "rb") as f:
        reader = make_reader(f)
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        attachments = list(reader.iter_attachments())
    assert "None" not in metadata["site"].values() and "local_g" not in metadata["site"]
    assert metadata["site"]["latitude_deg"] == "30.27"
    assert attachments and all(a.create_time > 0 for a in attachments)
    result = next(a for a in attachments if a.name.endswith(".result.json"))
    # attached when the run had finished: at the run clock's time then, not at 0
    assert result.log_time == pytest.approx(last_event_s * 1e9, abs=1e6) and result.log_time > 0


#: the topics the recorder holds for chunks of their own (bench.log.recorder: `_write_held`)
HELD_TOPICS = {TOPIC_CAN, TOPIC_SAMPLES}


def test_each_channel_is_in_log_time_order_and_only_held_topics_are_behind_others(run_log):
    """Issue 33, item 4: `mcap doctor` warns about `/can/raw` and `/imu/samples`. Each channel's messages are in
    log-time order in the file; only the two topics held for chunks of their own sit behind the other topics'
    messages of the same few seconds (docs/explanation/log-format.md)."""
    own, behind = log_time_order(run_log[0])
    assert set(own) >= HELD_TOPICS | {"/table/state", "/events"}
    assert not any(own.values()), own
    assert {topic for topic, count in behind.items() if count} <= HELD_TOPICS, behind


def _doctor(path) -> subprocess.CompletedProcess:
    return subprocess.run([os.environ["MCAP_CLI"], "doctor", str(path)], capture_output=True, text=True, timeout=120)


@pytest.mark.skipif(not os.environ.get("MCAP_CLI"), reason="MCAP_CLI (the reference mcap CLI) not given")
def test_the_reference_mcap_doctor_finds_no_error(run_log):
    proc = _doctor(run_log[0])
    assert proc.returncode == 0, proc.stdout + proc.stderr
    # and warns of nothing but the repeated records and the held topics' order (docs/explanation/log-format.md)
    for line in (proc.stdout + proc.stderr).splitlines():
        assert (line.startswith(("Duplicate schema records", "Duplicate channel records"))
                or any(f'on "{topic}" is less than the latest log time' in line for topic in HELD_TOPICS)), line
