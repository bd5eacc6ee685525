"""A run of several IMUs on hardware (issue 31): every unit's stream is checked before anything moves, and the one
line names the unit (a served simulated table, the IMUs on python-can's in-process virtual buses)."""

from __future__ import annotations

import uuid

from tests.e2e.test_several_imus import several_config
from tests.helpers.run import cli
from tests.unit.run.test_imu_check import _sender, served_table  # noqa: F401 - the fixture

RATE_HZ = 200.0      # several_config's units'


def test_every_unit_is_checked_before_anything_moves(tmp_path, served_table):  # noqa: F811 - the fixture
    controller, url = served_table
    a, b = (f"turntable-bench-units-{uuid.uuid4().hex[:8]}" for _ in range(2))
    units = (("A1", a, 0, '"z-up"'), ("B1", b, 0, '"x-up"'))
    config = tmp_path / "two.toml"
    config.write_text(several_config(units).replace('url = "sim"', f'url = "{url}"'), encoding="utf-8")
    good, good_bus = _sender(controller, a, rate_hz=RATE_HZ)
    fast, fast_bus = _sender(controller, b, rate_hz=4 * RATE_HZ)      # unit B1 sends four times too fast
    try:
        rc, _, stderr = cli(["run", "--config", str(config), "--out", str(tmp_path / "out"), "--no-db"])
    finally:
        for imu, bus in ((good, good_bus), (fast, fast_bus)):
            imu.stop()
            bus.shutdown()
    lines = stderr.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and "nothing moved" in lines[0], stderr
    assert f"the IMU on interface virtual channel {b} (unit B1) sends about" in lines[0]
    assert "the configuration says imu.rate_hz = 200" in lines[0]
    assert not any(axis.enabled for axis in controller.state().axes)
    assert not list(tmp_path.rglob("*.mcap"))
