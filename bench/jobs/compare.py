"""Compare calibration methods on one all-data log: the paper's section 5.2 and Table 5.

Each method is a (positions, rotations) schedule pair whose recorded steps are solved
on their own (`bench.finish.calibration.solve_recorded`); the table gives, per coefficient family,
the root-sum-square difference of each method from the last one listed (the all-data
solution) and, for a simulated log, from the simulator's truth, with the errors
defined as `bench.schedule_design.monte_carlo` defines them for the paper's Tables 2 and 4.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from bench.finish.calibration import NONE, load_subset_schedule, solve_recorded
from bench.finish.recorded import Recorded, SolveInputError
from bench.model.families import ERROR_TITLES, POSITION_KEYS, ROTATION_KEYS
from bench.model.quality import texts

#: `--compare` method names and the (positions, rotations) schedules they stand for.
METHODS = {"optimal": ("optimal-24", "optimal-5s6r"),
           "traditional": ("traditional-12", "traditional-3s6r"),
           "all": ("all-64", "all-96")}
#: Coefficient families of the comparison table, named as `bench.schedule_design.monte_carlo` names its errors.
FAMILY_KEYS = POSITION_KEYS + ROTATION_KEYS


@dataclass(frozen=True)
class Method:
    """A named (positions, rotations) schedule pair."""

    name: str
    positions: object        # Schedule or NONE
    rotations: object


def parse_methods(text: str) -> list[Method]:
    """`optimal,traditional,all` or pairs `POSITIONS+ROTATIONS` (builtin names or files), comma separated."""
    methods = []
    for item in (part.strip() for part in text.split(",")):
        if not item:
            raise SolveInputError(f"--compare {text!r}: empty method name")
        if item in METHODS:
            pos, rot = METHODS[item]
        elif "+" in item:
            pos, rot = item.split("+", 1)
        else:
            raise SolveInputError(f"--compare: unknown method {item!r} (known: {', '.join(METHODS)}, "
                                  "or POSITIONS+ROTATIONS schedules)")
        methods.append(Method(item, load_subset_schedule(pos, "positions"), load_subset_schedule(rot, "rotations")))
    if len(methods) < 2:
        raise SolveInputError("--compare needs at least two methods, the last is the reference")
    return methods


def _rss(values) -> float | None:
    values = list(values)
    return None if any(v is None for v in values) or not values else float(math.sqrt(sum(v * v for v in values)))


def family_differences(values: dict[str, float], reference: dict[str, float]) -> dict[str, float | None]:
    """Per family, the root-sum-square difference over its axes (display units; scale factors
    relative; direction cosines over all nine), as `bench.schedule_design.monte_carlo` defines the errors.
    None where either side lacks the family."""

    def diff(name, relative=False):
        if name not in values or name not in reference:
            return None
        return values[name] / reference[name] - 1.0 if relative else values[name] - reference[name]

    axes3, body = "xyz", "XYZ"
    return {
        "gyro_bias_dph": _rss(diff(f"D0_{s}") for s in axes3),
        "acc_bias_g": _rss(diff(f"K0_{s}") for s in axes3),
        "acc_scale": _rss(diff(f"Ka_{s}", True) for s in axes3),
        "acc_axes": _rss(diff(f"Ea_{a}{s}") for s in axes3 for a in body),
        "gyro_scale": _rss(diff(f"Kg_{s}", True) for s in axes3),
        "gyro_axes": _rss(diff(f"Eg_{a}{s}") for s in axes3 for a in body),
    }


@dataclass
class Comparison:
    """Each method's family differences from the reference (the last method) and from the truth."""

    reference: str
    rows: list[dict]                       # name, positions, rotations, vs_reference, vs_truth (or None)
    failures: list[str] = field(default_factory=list)

    def to_json(self) -> dict:
        return {"reference": self.reference, "families": list(FAMILY_KEYS), "methods": self.rows,
                "quality_failures": self.failures}


def compare(recorded: Recorded, methods: list[Method]) -> Comparison:
    """Solve each method's subset and tabulate its differences (SolveInputError if the logs lack one)."""
    solved = [(m, solve_recorded(recorded, m.positions, m.rotations)) for m in methods]
    reference = solved[-1][1].result.values()
    truth = recorded.truth.to_canonical() if recorded.truth is not None else None
    rows = []
    for m, r in solved:
        values = r.result.values()
        rows.append({"name": m.name, "positions": r.positions, "rotations": r.rotations,
                     "vs_reference": family_differences(values, reference),
                     "vs_truth": family_differences(values, truth) if truth is not None else None})
    return Comparison(methods[-1].name, rows, texts(solved[-1][1].failures))


def format_comparison(comparison: Comparison) -> str:
    """The comparison as text tables (like the paper's Table 5)."""
    width = max(12, *(len(r["name"]) + 2 for r in comparison.rows))
    head = f"{'method':<{width}}" + "".join(f"{ERROR_TITLES[k]:>17}" for k in FAMILY_KEYS)

    def line(name, diffs):
        return f"{name:<{width}}" + "".join(f"{'-' if diffs[k] is None else format(diffs[k], '.3e'):>17}"
                                            for k in FAMILY_KEYS)

    ref = comparison.rows[-1]
    out = [f"Difference from {comparison.reference} ({ref['positions'] or NONE} + {ref['rotations'] or NONE}); "
           "root-sum-square over the axes, scale factors relative, direction cosines over all nine", head]
    out += [line(r["name"], r["vs_reference"]) for r in comparison.rows[:-1]]
    if comparison.rows[-1]["vs_truth"] is not None:
        out += ["", "Error from the simulator's truth", head]
        out += [line(r["name"], r["vs_truth"]) for r in comparison.rows]
    out += ["", "methods: " + "; ".join(f"{r['name']} = {r['positions'] or NONE} + {r['rotations'] or NONE}"
                                        for r in comparison.rows)]
    return "\n".join(out) + "\n"


__all__ = ["FAMILY_KEYS", "METHODS", "Comparison", "Method", "compare", "family_differences",
           "format_comparison", "parse_methods"]
