"""First-order black-box sensitivity, noise sigmas and `bench schedules analyze`."""

import numpy as np
import pytest

from bench.cli.main import main
from bench.model.imu import ImuCoefficients, NoiseModel
from bench.schedule_design.sensitivity import (
    ANGLE_NAMES,
    position_noise_sigma,
    position_sensitivity,
    rotation_noise_sigma,
    rotation_sensitivity,
)
from bench.solve.methods import SolverError
from schedules import load_builtin

IDEAL = ImuCoefficients.ideal()


def _angles(name):
    return np.array([p.angles_deg for p in load_builtin(name).positions])


def _turns(name):
    return list(load_builtin(name).rotations)


def test_optimal_24_leaves_only_the_inner_zero_offset_in_the_xy_axis_terms():
    sens = position_sensitivity(_angles("optimal-24"), imu=IDEAL)
    assert sorted(sens.remaining_pairs()) == [("Ea_Xy", "inner.gamma"), ("Ea_Yx", "inner.gamma")]
    # A rotation of the body about Z by gamma: Ea_Yx = +gamma, Ea_Xy = -gamma (arcsec per arcsec).
    assert sens.row("Ea_Yx")[8] == pytest.approx(1.0, abs=1e-6)
    assert sens.row("Ea_Xy")[8] == pytest.approx(-1.0, abs=1e-6)


def test_optimal_24_with_a_misaligned_imu_still_cancels_every_bias_and_scale():
    sens = position_sensitivity(_angles("optimal-24"))
    fams = sens.families_remaining()
    assert fams["D0"] == fams["K0"] == fams["Ka"] == []
    assert fams["Ea"] == ["inner.gamma"]
    # Ea_Xz/Ea_Yz pick up gamma times the z accelerometer's own misalignment (< 1e-3).
    assert abs(sens.row("Ea_Xz")[8]) < 1e-3 and abs(sens.row("Ea_Yz")[8]) < 1e-3


def test_traditional_12_leaves_first_order_bias_terms():
    sens = position_sensitivity(_angles("traditional-12"), imu=IDEAL)
    fams = sens.families_remaining()
    assert fams["D0"] and fams["K0"]
    assert set(fams["Ea"]) > {"inner.gamma"}
    # 1 arcsec of middle-frame beta error: a gyro bias error of order Omega * 1 arcsec.
    assert np.max(np.abs(sens.row("D0_x"))) > 1e-5  # deg/h per arcsec


def test_optimal_5s6r_geometry_leaves_only_the_inner_zero_offset():
    sens = rotation_sensitivity(_turns("optimal-5s6r"), imu=IDEAL)
    rem = sens.remaining_geometric
    assert [(sens.names[i], ANGLE_NAMES[j]) for i, j in zip(*np.nonzero(rem))] == [
        ("Eg_Yx", "inner.gamma"), ("Eg_Xy", "inner.gamma")]
    # What is left beyond that is Earth-rate coupling: ~T*Omega/(2 pi N) relative, far below 1e-3.
    earth = sens.remaining & ~rem
    assert earth.any() and np.max(np.abs(sens.matrix[earth] / sens.natural[np.nonzero(earth)[0]])) < 1e-3


def test_traditional_3s6r_leaves_first_order_axis_terms_and_all_96_cancels_all_but_gamma():
    trad = rotation_sensitivity(_turns("traditional-3s6r"), imu=IDEAL)
    assert set(trad.families_remaining()["Eg"]) > {"inner.gamma"}
    # With a misaligned IMU the scale factors pick up first-order terms too (misalignment x angle).
    assert rotation_sensitivity(_turns("traditional-3s6r")).families_remaining()["Kg"]
    every = rotation_sensitivity(_turns("all-96"), imu=IDEAL)
    assert sorted(every.remaining_pairs()) == [("Eg_Xy", "inner.gamma"), ("Eg_Yx", "inner.gamma")]


def test_sensitivity_matches_a_monte_carlo_difference_at_small_angles():
    # Linear prediction vs the actual solve at a 0.5 arcsec black box on one angle.
    from bench.model.earth import Site
    from bench.model.units import ARCSEC, G0
    from bench.schedule_design.sensitivity import solve_positions_batch
    angles = _angles("traditional-12")
    sens = position_sensitivity(angles)
    box = np.zeros((1, 3, 3))
    box[0, 1, 1] = 0.5 * ARCSEC
    solved = solve_positions_batch(angles, box, __import__("bench.model.imu", fromlist=["x"]).default_sim_imu(), Site())
    predicted = 0.5 * sens.row("K0_z")[4]
    actual = (solved["K0"][0, 2] - __import__("bench.model.imu", fromlist=["x"]).default_sim_imu().acc_bias[2]) / G0
    assert actual == pytest.approx(predicted, rel=1e-3)


def test_noise_sigma_scales_with_dwell_and_noise():
    angles = _angles("optimal-24")
    white = NoiseModel(0.002, 0.0, 10.0, 0.0, 300.0, False)
    s60 = position_noise_sigma(angles, white, 60.0)
    s240 = position_noise_sigma(angles, white, 240.0)
    assert s240["K0_x"] == pytest.approx(s60["K0_x"] / 2, rel=1e-6)
    assert s240["D0_z"] == pytest.approx(s60["D0_z"] / 2, rel=1e-6)
    # 24 positions, VRW 10 ug/rt Hz, 60 s: sigma of the bias = 10 ug / sqrt(60) / sqrt(24).
    assert s60["K0_x"] == pytest.approx(10e-6 / np.sqrt(60) / np.sqrt(24), rel=1e-3)
    rot = rotation_noise_sigma(_turns("optimal-5s6r"), white)
    rot_slow = rotation_noise_sigma(_turns("optimal-5s6r"), white, rate_dps=2.5)
    assert rot_slow["Kg_x"] == pytest.approx(2 * rot["Kg_x"], rel=1e-3)  # ARW*sqrt(T), T 4x longer


def test_rank_deficient_schedule_is_a_solver_error():
    with pytest.raises(SolverError, match="determine only"):
        position_sensitivity(_angles("table-check-324"))


def test_cli_analyze_positions(capsys):
    assert main(["schedules", "analyze", "traditional-12", "--runs", "5"]) == 0
    out = capsys.readouterr().out
    assert "D0: remains middle.beta" in out
    assert "Plan duration estimate" in out
    assert "traditional-12" in out and "optimal-24" in out  # Monte Carlo beside the optimal


def test_cli_analyze_rotations(capsys):
    assert main(["schedules", "analyze", "optimal-5s6r", "--runs", "5", "--turn-rate-dps", "20"]) == 0
    out = capsys.readouterr().out
    assert "Eg: remains inner.gamma" in out and "Earth coupling" in out


def test_cli_analyze_errors(tmp_path, capsys):
    assert main(["schedules", "analyze", "no-such-schedule"]) == 1
    assert "no such schedule file" in capsys.readouterr().err
    bad = tmp_path / "bad.toml"
    bad.write_text('format = "turntable-bench/schedule"\nversion = 1\nname = "x"\nkind = "positions"\n'
                   'description = "d"\n[[position]]\nangles_deg = [0, 45, 0]\n')
    assert main(["schedules", "analyze", str(bad)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"{bad}:7: position[1].angles_deg:") and "\n" not in err
