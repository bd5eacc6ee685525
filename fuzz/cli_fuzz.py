"""Fuzz `bench run --config F --dry-run` and `bench schedules validate F` as subprocesses.

Not collected by pytest (the suite's in-process fuzz test is tests/unit/config/test_config_fuzz.py).
Writes mutated copies of bench.example.toml and of shipped schedules (tests/helpers/mutations.py),
runs each command with a timeout and a 4 GiB address-space limit, and prints a table of inputs
tried, crashes (a traceback or a death by signal), hangs (timeouts), other multi-line errors
and the peak RSS over all runs. A config sometimes names a mutated schedule file beside it.

    python fuzz/cli_fuzz.py [--code ROOT ...] [--configs 200] [--schedules 200] [--seed 1]
                                  [--jobs 2] [--timeout-s 60] [--out DIR] [--json FILE]

`--code ROOT` runs the bench from another checkout (e.g. a `git worktree add /tmp/before <commit>`)
through PYTHONPATH; given twice, every input runs against both (before and after a change);
default: this checkout. Besides the random inputs, a fixed set named in issue 13 item 8 is run
(deep nesting, 1e308 dwell, 400-digit numbers, /dev/zero as DBC, schedule or file, ...).
Inputs and outputs stay in --out (default: a temp dir).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import resource
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tests.helpers.mutations import mutate  # noqa: E402

SCHEDULES = ("optimal-24", "optimal-5s6r", "table-check-324", "all-96", "traditional-12")
ADDRESS_SPACE_LIMIT = 4 << 30


def make_inputs(out: Path, n_configs: int, n_schedules: int, seed: int) -> list[tuple[str, Path]]:
    rnd = random.Random(seed)
    example = (REPO / "bench.example.toml").read_text(encoding="utf-8")
    texts = {name: (REPO / "schedules" / f"{name}.toml").read_text(encoding="utf-8") for name in SCHEDULES}
    jobs: list[tuple[str, Path]] = []
    for i in range(n_schedules):
        name = SCHEDULES[i % len(SCHEDULES)]
        path = out / "schedules" / f"s{i:04d}-{name}.toml"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(mutate(texts[name], rnd))
        jobs.append(("schedule", path))
    for i in range(n_configs):
        folder = out / "configs" / f"c{i:04d}"
        folder.mkdir(parents=True, exist_ok=True)
        text = example
        if rnd.random() < 0.25:  # the plan names a mutated schedule file beside the config
            name, key = rnd.choice((("optimal-24", "positions"), ("optimal-5s6r", "rotations")))
            (folder / "mine.toml").write_bytes(mutate(texts[name], rnd))
            text = text.replace(f'{key} = "{name}"', f'{key} = "mine.toml"', 1)
        (folder / "bench.toml").write_bytes(mutate(text, rnd))
        jobs.append(("config", folder / "bench.toml"))
    return jobs


def directed_inputs(out: Path) -> list[tuple[str, Path]]:
    """The inputs named in issue 13 (item 8), beside the random ones: deep nesting, a 1e308 dwell,
    400-digit numbers, /dev/zero as a DBC, a schedule or the file itself, absurd rates and turns."""
    example = (REPO / "bench.example.toml").read_text(encoding="utf-8")
    rotations = (REPO / "schedules" / "optimal-5s6r.toml").read_text(encoding="utf-8")
    positions = (REPO / "schedules" / "optimal-24.toml").read_text(encoding="utf-8")
    big = "1" + "0" * 399

    def sub(text: str, old: str, new: str) -> str:
        assert old in text, old
        return text.replace(old, new, 1)

    configs = {
        "deep-array": sub(example, "seed = 0 ", "seed = " + "[" * 5000 + "]" * 5000 + " "),
        "deep-inline": sub(example, "seed = 0 ", "seed = " + "{a=" * 5000 + "1" + "}" * 5000 + " "),
        "dwell-1e308": sub(example, "dwell_s = 60.0", "dwell_s = 1e308"),
        "revolutions-400-digits": sub(example, "revolutions = 1 ", f"revolutions = {big} "),
        "latitude-400-digits": sub(example, "latitude_deg = 30.27", f"latitude_deg = {big}"),
        "seed-400-digits": sub(example, "seed = 0 ", f"seed = {big} "),
        "dbc-dev-zero": sub(example, '# dbc = "my-imu.dbc"', 'dbc = "/dev/zero"'),
        "positions-dev-zero": sub(example, 'positions = "optimal-24"', 'positions = "/dev/zero"'),
        "positions-nul": sub(example, 'positions = "optimal-24"', 'positions = "a\\u0000b"'),
        "positions-long-name": sub(example, 'positions = "optimal-24"', 'positions = "' + "p" * 5000 + '"'),
        "positions-tilde-user": sub(example, 'positions = "optimal-24"', 'positions = "~nosuchuser-fuzz/p.toml"'),
        "slow-turns-1e12-revolutions": sub(sub(example, "turn_rate_dps = 10.0", "turn_rate_dps = 1e-300"),
                                           "revolutions = 1 ", "revolutions = 1000000000000 "),
        "dwell-2-days": sub(example, "dwell_s = 60.0", "dwell_s = 172800"),
        "black-box-1e308": sub(example, "black_box_arcsec = 20.0", "black_box_arcsec = 1e308"),
        "sim-imu-400-digits": sub(example, "D0_x = 0.05", f"D0_x = {big}"),
        "big-file": example + ("# padding\n" * 200_000),
    }
    schedules = {
        "deep-array": rotations + "\nx = " + "[" * 5000 + "]" * 5000 + "\n",
        "angle-400-digits": sub(positions, "angles_deg = [0, 0, 0]", f"angles_deg = [0, 0, {big}]"),
        "revolutions-400-digits": sub(rotations, "revolutions = 1", f"revolutions = {big}"),
        "revolutions-1e12": sub(rotations, "revolutions = 1", "revolutions = 1000000000000"),
        "group-400-digits": sub(positions, "group = 1", f"group = {big}"),
        "big-file": positions + ("# padding\n" * 200_000),
    }
    jobs: list[tuple[str, Path]] = []
    for name, text in configs.items():
        folder = out / "directed" / f"config-{name}"
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "bench.toml").write_text(text, encoding="utf-8")
        jobs.append(("config", folder / "bench.toml"))
    for name, text in schedules.items():
        path = out / "directed" / f"schedule-{name}.toml"
        path.write_text(text, encoding="utf-8")
        jobs.append(("schedule", path))
    jobs += [("config", Path("/dev/zero")), ("schedule", Path("/dev/zero"))]
    return jobs


def run_limited(argv: list[str], cwd: Path, env: dict, out, err, timeout_s: float,
                as_limit: int = ADDRESS_SPACE_LIMIT) -> tuple[int, bool, resource.struct_rusage, float]:
    """Run `argv` in its own session under an address-space limit, killed after `timeout_s`:
    (exit code, whether it hung, its resource usage (ru_maxrss: peak RSS, KiB), seconds)."""
    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (as_limit, as_limit))

    proc = subprocess.Popen(argv, cwd=cwd, env=env, stdin=subprocess.DEVNULL, stdout=out, stderr=err,
                            preexec_fn=limit, start_new_session=True)
    start, hung = time.monotonic(), False
    while True:
        pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
        if pid:
            break
        if time.monotonic() - start > timeout_s:
            hung = True
            os.killpg(proc.pid, signal.SIGKILL)
            pid, status, usage = os.wait4(proc.pid, 0)
            break
        time.sleep(0.02)
    proc.returncode = os.waitstatus_to_exitcode(status)  # reaped here, not by Popen
    return proc.returncode, hung, usage, time.monotonic() - start


def run_one(kind: str, path: Path, logs: Path, code: Path, timeout_s: float) -> dict:
    argv = ([sys.executable, "-m", "bench.cli", "run", "--config", str(path), "--dry-run"] if kind == "config"
            else [sys.executable, "-m", "bench.cli", "schedules", "validate", str(path)])
    env = {**os.environ, "PYTHONPATH": str(code)}
    with open(logs.with_suffix(".stdout"), "wb") as out, open(logs.with_suffix(".stderr"), "wb") as err:
        returncode, hung, usage, wall_s = run_limited(argv, logs.parent, env, out, err, timeout_s)
    stderr = logs.with_suffix(".stderr").read_text(encoding="utf-8", errors="replace")
    lines = stderr.strip().splitlines()
    if hung:
        outcome = "hang"
    elif "Traceback (most recent call last)" in stderr or returncode < 0:
        outcome = "crash"
    elif returncode == 0:
        outcome = "ok"
    elif len(lines) == 1:
        outcome = "error"
    else:
        outcome = "not one line"
    last = lines[-1] if lines else ""
    return {"kind": kind, "path": str(path), "outcome": outcome, "exit": returncode,
            "wall_s": round(wall_s, 2), "max_rss_kb": usage.ru_maxrss, "last_line": last[:300]}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--code", type=Path, action="append",
                        help="checkout whose bench is run (PYTHONPATH); repeat it to run each input against "
                             "each (e.g. before and after a change); default: this checkout")
    parser.add_argument("--configs", type=int, default=200)
    parser.add_argument("--schedules", type=int, default=200)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--timeout-s", type=float, default=60.0)
    parser.add_argument("--out", type=Path, help="where the inputs and outputs go (default: a temp dir)")
    parser.add_argument("--json", type=Path, help="write every run's record here")
    args = parser.parse_args()
    codes = [code.resolve() for code in (args.code or [REPO])]
    out = args.out or Path(tempfile.mkdtemp(prefix="cli-fuzz-"))
    inputs = [("random", kind, path) for kind, path in make_inputs(out, args.configs, args.schedules, args.seed)]
    inputs += [("directed", kind, path) for kind, path in directed_inputs(out)]
    (out / "logs").mkdir(exist_ok=True)
    runs = [(c, *job) for c in range(len(codes)) for job in inputs]

    def run(i: int) -> dict:
        c, origin, kind, path = runs[i]
        return {"code": str(codes[c]), "origin": origin,
                **run_one(kind, path, out / "logs" / f"{c}-{i:05d}", codes[c], args.timeout_s)}

    with ThreadPoolExecutor(args.jobs) as pool:
        records = list(pool.map(run, range(len(runs))))
    if args.json:
        args.json.write_text(json.dumps(records, indent=1), encoding="utf-8")
    print(f"inputs: {out}")
    print("| code | command | inputs | ok | one-line error | crashes | hangs | not one line | peak RSS |")
    print("|---|---|---|---|---|---|---|---|---|")
    for code in codes:
        for origin in ("random", "directed"):
            for kind, command in (("config", "bench run --config F --dry-run"),
                                  ("schedule", "bench schedules validate F")):
                mine = [r for r in records if (r["code"], r["kind"], r["origin"]) == (str(code), kind, origin)]
                counts = Counter(r["outcome"] for r in mine)
                peak = max((r["max_rss_kb"] for r in mine), default=0) / 1024
                print(f"| {code} | `{command}` ({origin}) | {len(mine)} | {counts['ok']} | {counts['error']} | "
                      f"{counts['crash']} | {counts['hang']} | {counts['not one line']} | {peak:.0f} MiB |")
    bad = [r for r in records if r["outcome"] in ("crash", "hang", "not one line")]
    kinds = Counter((r["code"], r["origin"], r["kind"],
                     r["last_line"].split(":")[0] if r["outcome"] == "crash" else r["outcome"]) for r in bad)
    for (code, origin, kind, what), n in kinds.most_common():
        print(f"  {n:4d} x {code} {origin} {kind}: {what}")
    for r in records:
        if r["origin"] == "directed":
            print(f"  {r['code']} directed {r['kind']} {r['path']}: {r['outcome']}, exit {r['exit']}, "
                  f"{r['max_rss_kb'] / 1024:.0f} MiB, {r['wall_s']} s: {r['last_line'][:160]}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
