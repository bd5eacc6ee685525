"""Benchmark: several IMUs in one simulated run against one IMU of the same plan (issue 31, "Must show").

Issue 31 asks that N units on two faces and two buses each recover their truth within U, with sigmas at most 1.2x
those of a single-unit run of the same plan and a wall time at most 1.3x.

Run: python benchmarks/several_imus.py [--units 4] [--plan short|optimal] [--dwell-s 2] [--out DIR]

Runs `bench run --sim --config` in a fresh process once with one [[imu]] unit on each face used (z-up, x-up) and
once with `--units` units (alternating z-up and x-up, half on each of two virtual buses, ids offset on a shared
bus), then compares each unit with the single unit on its face: the largest sigma ratio (the direction-cosine
diagonals, second order and set by each unit's own misalignments, apart), its worst |error| / U against its truth,
and the CPU time of each process (the simulated run time is the same plan's: equal by construction). The machine
is shared: CPU time, not wall time, is the comparable figure. One run of each (the "medians" are single runs).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

import results

REPO = Path(__file__).resolve().parents[1]
PLANS = {"short": ("traditional-12", "traditional-3s6r"), "optimal": ("optimal-24", "optimal-5s6r")}
FACES = ("z-up", "x-up")


def config_text(units: list[tuple[str, str, int, str]], plan: str, dwell_s: float) -> str:
    positions, rotations = PLANS[plan]
    entries = "".join(f'[[imu]]\ninterface = "virtual"\nchannel = "{bus}"\nrate_hz = 200.0\nid_offset = {offset}\n'
                      f'mounting = "{face}"\nidentity = {{ model = "sim", serial = "{serial}" }}\n\n'
                      for serial, bus, offset, face in units)
    return (f'format = "turntable-bench/config"\nversion = 1\n[site]\nlatitude_deg = 30.0\n[table]\nurl = "sim"\n'
            f'dialect = "scpi"\n\n{entries}[plan]\npositions = "{positions}"\nrotations = "{rotations}"\n'
            f"dwell_s = {dwell_s}\nsettle_s = 2.0\nturn_rate_dps = 10.0\nrevolutions = 1\n"
            "[sim]\nseed = 0\nblack_box_arcsec = 20.0\nnoise = true\n")


def run(folder: Path, units, plan: str, dwell_s: float) -> tuple[float, dict[str, dict]]:
    """One `bench run` in a fresh process: (its CPU time, s; serial -> result)."""
    folder.mkdir(parents=True)
    config = folder / "bench.toml"
    config.write_text(config_text(units, plan, dwell_s), encoding="utf-8")
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run([sys.executable, "-m", "bench.cli", "run", "--config", str(config), "--out", str(folder / "run"),
                    "--no-db", "--quiet"], cwd=REPO, check=True, stdout=subprocess.DEVNULL)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu_s = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    found = {}
    for serial, *_ in units:
        (path,) = (folder / "run").glob(f"*.{serial}.result.json")
        found[serial] = json.loads(path.read_text(encoding="utf-8"))
    return cpu_s, found


def diagonal(name: str) -> bool:
    return name[0] == "E" and name[-2].upper() == name[-1].upper()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=4)
    parser.add_argument("--plan", choices=PLANS, default="short")
    parser.add_argument("--dwell-s", type=float, default=2.0)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="several-imus-"))
    singles = {}
    for face in FACES:
        cpu_s, solved = run(out / f"single-{face}", [("S1", "bus-a", 0, face)], args.plan, args.dwell_s)
        singles[face] = (cpu_s, solved["S1"]["coefficients"])
        print(f"single unit {face}: CPU {cpu_s:.1f} s")
    units = [(f"U{k + 1}", "bus-a" if k < (args.units + 1) // 2 else "bus-b", 16 * (k % ((args.units + 1) // 2)),
              FACES[k % 2]) for k in range(args.units)]
    cpu_s, solved = run(out / "several", units, args.plan, args.dwell_s)
    print(f"{args.units} units: CPU {cpu_s:.1f} s ({cpu_s / singles['z-up'][0]:.2f}x one unit's)")
    medians_s = {f"one unit ({face}): CPU of bench run": singles[face][0] for face in FACES}
    medians_s[f"{args.units} units: CPU of bench run"] = cpu_s
    ratios = {f"{args.units} units / one unit (z-up): CPU": cpu_s / singles["z-up"][0]}
    for serial, _, _, face in units:
        coefficients, truth = solved[serial]["coefficients"], solved[serial]["sim_truth"]["coefficients"]
        single = singles[face][1]
        ratio = max(coefficients[n]["sigma"] / single[n]["sigma"] for n in coefficients if not diagonal(n))
        worst = max(abs(e["value"] - truth[n]["value"]) / e["expanded"] for n, e in coefficients.items())
        print(f"  {serial} ({face}): sigma / single's <= {ratio:.3f}; worst |error| / U {worst:.2f}")
        ratios[f"{serial} ({face}): largest sigma / the single unit's"] = ratio
        ratios[f"{serial} ({face}): worst |error| / U"] = worst
    path = results.record("several_imus", medians_s=medians_s, ratios=ratios,
                          parameters={"units": args.units, "plan": args.plan, "dwell_s": args.dwell_s, "runs": 1})
    print(f"(files in {out}; figures in {path})")


if __name__ == "__main__":
    main()
