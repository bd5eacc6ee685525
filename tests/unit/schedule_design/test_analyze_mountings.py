"""`bench schedules analyze --config / --mounting`: the plan's observability as each mounted unit sees it (issue 31
item 8)."""

from pathlib import Path

import numpy as np
import pytest

from bench.cli.main import main
from bench.config.units import FACES
from bench.model.imu import NoiseModel
from bench.schedule_design.extended import extended_observability
from bench.schedule_design.sensitivity import (
    position_noise_sigma,
    position_sensitivity,
    rotation_noise_sigma,
)
from schedules import load_builtin

REPO = Path(__file__).resolve().parents[3]
NOISE = NoiseModel()


def _angles(name):
    return np.array([p.angles_deg for p in load_builtin(name).positions])


def _weak_plan(path: Path) -> Path:
    """24 positions: the fixture's z up or down 20 times, its x and y once each up and down."""
    steps = [(o, m, i) for o in (0, 90, 180, 270) for i in (0, 90, 180, 270) for m in (0, 180)][:20]
    steps += [(0, 90, 0), (0, 270, 0), (0, 90, 90), (0, 270, 90)]
    path.write_text('format = "turntable-bench/schedule"\nversion = 1\nname = "weak-x"\nkind = "positions"\n'
                    'description = "z up and down 20 times, x and y once each"\nsource = "test"\n'
                    + "".join(f"\n[[position]]\nangles_deg = [{o}, {m}, {i}]\ngroup = {k // 2 + 1}\n"
                              for k, (o, m, i) in enumerate(steps)))
    return path


def _section(out: str, label: str) -> str:
    """One unit's block of the output."""
    block = out.split(f"unit {label}:\n", 1)[1]
    return block.split("\nunit ", 1)[0].split("\n\n", 1)[0]


@pytest.mark.parametrize("face", sorted(FACES))
def test_optimal_24_is_observed_alike_on_every_face(face):
    """The paper's plan is symmetric: every face sees the same sigmas, coefficient by coefficient."""
    mounting = np.array(FACES[face], dtype=float)
    angles = _angles("optimal-24")
    plain = position_noise_sigma(angles, NOISE, 60.0)
    mounted = position_noise_sigma(angles, NOISE, 60.0, mounting=mounting)
    assert mounted.keys() == plain.keys()
    for name, value in plain.items():
        assert mounted[name] == pytest.approx(value, rel=1e-9)


def test_a_weak_plan_leaves_a_different_axis_weak_on_each_face(tmp_path):
    """z up and down 20 times out of 24: the unit's axis along the fixture's z is the well observed one."""
    from schedules import load_schedule
    angles = np.array([p.angles_deg for p in load_schedule(_weak_plan(tmp_path / "weak.toml")).positions])
    well = {"z-up": "z", "z-down": "z", "x-up": "x", "x-down": "x", "y-up": "y", "y-down": "y"}
    for face, axis in well.items():
        sigma = position_noise_sigma(angles, NOISE, 60.0, mounting=np.array(FACES[face], dtype=float))
        ka = {s: sigma[f"Ka_{s}"] for s in "xyz"}
        # sqrt(20 / 2): the well observed axis has ten times the dwells of each other one
        for s in "xyz":
            expected = ka[axis] if s == axis else ka[axis] * np.sqrt(10.0)
            assert ka[s] == pytest.approx(expected, rel=0.02), (face, s, ka)


def test_the_fixture_axes_give_the_single_unit_figures_exactly():
    """An identity mounting is no rotation: the figures are today's bit for bit (the CLI passes None for it)."""
    angles = _angles("traditional-12")
    eye = np.eye(3)
    assert position_noise_sigma(angles, NOISE, 60.0, mounting=eye) == position_noise_sigma(angles, NOISE, 60.0)
    assert np.array_equal(position_sensitivity(angles, mounting=eye).matrix, position_sensitivity(angles).matrix)
    turns = list(load_builtin("optimal-5s6r").rotations)
    assert rotation_noise_sigma(turns, NOISE, mounting=eye) == rotation_noise_sigma(turns, NOISE)
    assert ([r.sigma for r in extended_observability(angles, [], NOISE, mounting=eye)]
            == [r.sigma for r in extended_observability(angles, [], NOISE)])


def test_cli_prints_every_unit_of_a_configuration(capsys):
    assert main(["schedules", "analyze", "optimal-24", "--runs", "2",
                 "--config", str(REPO / "multi-imu.example.toml")]) == 0
    out = capsys.readouterr().out
    for label in ("SIM-A1 (z-up)", "SIM-A2 (x-up)", "SIM-B1 (z-up)", "SIM-B2 (matrix)"):
        assert f"unit {label}:" in out
    # the z-up unit's figures are the single unit's, printed above them
    single = out.split("Noise-driven 1-sigma", 1)[1].split("\n\n", 1)[0]
    for line in single.splitlines()[1:]:
        name, value = line.split()[:2]
        assert f"{name} {value}" in _section(out, "SIM-A1 (z-up)")
    extended = out.split("Extended model", 1)[1].split("\n\n", 1)[0].splitlines()[1:]
    assert "\n".join("  " + line for line in extended) in _section(out, "SIM-A1 (z-up)")
    # the paper's plan: the x-up units see the same sigmas, in the same place
    assert (_section(out, "SIM-A2 (x-up)").split("noise-driven", 1)[1]
            == _section(out, "SIM-A1 (z-up)").split("noise-driven", 1)[1])


def test_cli_shows_the_weak_axis_of_each_mounting(tmp_path, capsys):
    plan = _weak_plan(tmp_path / "weak.toml")
    assert main(["schedules", "analyze", str(plan), "--runs", "1", "--mounting", "z-up",
                 "--mounting", "x-up"]) == 0
    out = capsys.readouterr().out
    z_up, x_up = _section(out, "--mounting z-up"), _section(out, "--mounting x-up")
    assert "Ka_x 1.65, Ka_y 1.65, Ka_z 0.522" in z_up
    assert "Ka_x 0.522, Ka_y 1.65, Ka_z 1.65" in x_up
    assert "3.16x the best of its family" in x_up


def test_cli_refuses_a_bad_configuration_in_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text((REPO / "multi-imu.example.toml").read_text().replace('mounting = "x-up"', 'mounting = "x-upp"'))
    assert main(["schedules", "analyze", "optimal-24", "--config", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.toml" in err[0] and "mounting" in err[0]
