"""studies/higher_order_bias.py: the bias of the 30-coefficient solve with the higher-order truth on (issue 30)."""

from __future__ import annotations

from bench.sim.acquire import AcquisitionTiming
from studies.higher_order_bias import study, table


def test_a_second_order_accelerometer_biases_the_solve_and_fails_its_residual_test_a_lever_arm_does_not():
    # the default plan's positions and turns at 100 Hz: the static solve cannot see the size effect (no rate at a
    # dwell), while Q a^2 at +-1 g looks like a bias the 24 positions cannot tell apart
    rows = study("nav-fog", seed=2, rate_hz=100.0, timing=AcquisitionTiming(),
                 terms=["acc_second_order_ug_per_g2", "acc_lever_arm_mm"])
    reference, second_order, lever = rows
    assert set(reference.bias_sigma.values()) == {0.0} and reference.flags == []
    name, worst = second_order.largest(1)[0]
    assert name.startswith("K0_") and abs(worst) > 3.0
    assert {"accelerometers x", "accelerometers y", "accelerometers z"} <= set(second_order.flags)
    assert max(abs(v) for v in lever.bias_sigma.values()) < 1.0 and lever.flags == []
    assert "| acc_second_order_ug_per_g2 | K0_" in table("nav-fog", rows)
