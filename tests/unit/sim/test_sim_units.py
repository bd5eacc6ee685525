"""Several simulated IMUs (issue 31): a unit's view of the table with its mounting, each unit's own truth."""

from __future__ import annotations

import numpy as np

from bench.config.units import FACES
from bench.model.earth import Site
from bench.model.families import BODY_AXES, SENSOR_AXES
from bench.model.imu import default_sim_imu
from bench.sim.table import SimTable
from bench.sim.units import mounted_view, unit_seed, unit_truth


def test_a_mounted_view_is_the_table_seen_from_the_unit_every_command_included():
    box = np.random.default_rng(1).standard_normal((3, 3)) * 1e-4
    table = SimTable(Site(), black_box_rad=box)
    x_up = np.array(FACES["x-up"], float)
    view = mounted_view(table, x_up)
    table.move_to(0.0, (30.0, 45.0, 60.0), rate_dps=20.0)        # commanded after the view was made
    table.turn(20.0, 2, "ccw", 1, 20.0)
    mounted = SimTable(Site(), black_box_rad=box, mounting=x_up)
    mounted.move_to(0.0, (30.0, 45.0, 60.0), rate_dps=20.0)
    mounted.turn(20.0, 2, "ccw", 1, 20.0)
    times = np.linspace(0.0, 60.0, 301)
    for got, want in zip(view.body_rate_and_specific_force(times), mounted.body_rate_and_specific_force(times)):
        np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(view.piece_starts(), table.piece_starts())
    assert table.mounting is None                                 # the table itself is not changed
    # at rest at zero the x-up unit feels gravity's specific force along its own x
    at_rest = SimTable(Site())
    force = mounted_view(at_rest, x_up).specific_force(0.0)
    assert np.argmax(np.abs(force)) == 0 and force[0] > 9.7


def test_every_unit_but_the_first_has_its_own_truth_with_unit_rows():
    base = default_sim_imu()
    assert unit_truth(base, 0, 5) is base
    one, two = unit_truth(base, 1, 5), unit_truth(base, 2, 5)
    assert one.to_canonical() != two.to_canonical() and one.to_canonical() == unit_truth(base, 1, 5).to_canonical()
    for truth in (one, two):
        values = truth.to_canonical()
        for prefix in ("Eg", "Ea"):
            for sensor in SENSOR_AXES:
                assert abs(sum(values[f"{prefix}_{a}{sensor}"] ** 2 for a in BODY_AXES) - 1.0) < 1e-12
        assert max(abs(values[n] - base.to_canonical()[n]) for n in values if n.startswith("D0")) < 0.5
    assert unit_seed(7, 0) == 7 and unit_seed(7, 1) != unit_seed(7, 2)
