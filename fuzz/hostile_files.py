"""Run the bench's file-reading commands on hostile files and content, as subprocesses (issue 34 items 3-6).

Not collected by pytest (the suite's tests are tests/unit/cli/test_hostile_files.py and
tests/unit/cli/test_hostile_content.py).
Records a short simulated run and a thermal one (or takes `--base LOG --thermal LOG`), then writes, with
the generators below, logs and JSON files and runs the commands that read them:

- labels: step labels `T²-P01`, `T` + 5,000 digits, other scripts' digits, 100 kB labels;
- dates: `run.started_utc` / `finished_utc` out of range, in another zone at year 1, not dates;
- huge numbers and NaN: 10**400, 1e999, -1e300, NaN, Infinity in thermal steps, chamber and table states,
  events, CAN frame times, and in result, thermal, noise and table-check files (also through a
  configuration's `[imu] noise`, `[acceptance] reference`, `[table] check`);
- deep nesting: 5,000 levels in those JSON files and in log messages;
- non-regular files: a FIFO, /dev/zero, a folder and a socket as LOG, RESULT, --against, --calibration,
  --resume, and outputs that are an input (a hard link) or another run's log;
- 1 MB text fields: alarm texts, fault texts, event labels.

Each command runs with a timeout and an address-space limit (`--as-limit-gib`, 4 by default); prints the
runs, tracebacks (a traceback or a death by signal), hangs (timeouts), the worst peak RSS (`wait4`) and
the worst time, with the inputs that gave them, and every traceback's last line.

    python fuzz/hostile_files.py [--code ROOT] [--base LOG --thermal LOG] [--random 60] [--seed 34]
                                       [--jobs 2] [--timeout-s 120] [--out DIR] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import random
import socket
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from fuzz.cli_fuzz import run_limited  # noqa: E402
from tests.helpers import mcap_surgery as ms  # noqa: E402

GiB = 1 << 30
BIG = "1" + "0" * 400
NUMBERS = (BIG, "1e999", "-1e999", "-1e300", "1e300", "NaN", "Infinity", "-Infinity", "1" * 5000, "5e-324",
           "-" + BIG)
DEEP = "[" * 5000 + "]" * 5000
LABELS = ("T²-P01", "T" + "1" * 5000, "T١-P01", "T0-P01", "T-P01", "T99999999-P01", "P" * 100_000, "", "T1-",
          "T\u0000-P01", "../../etc/passwd")
DATES = ("0001-01-01T00:00:00+05:00", "9999-12-31T23:59:59-05:00", "2026-13-45T99:99:99Z", "x" * 100_000, "",
         "0000-00-00", "2026-11-24T02:49:01+99:00", "+275760-09-13T00:00:00Z")


# -- generators ------------------------------------------------------------------------------------------------

def _raw(doc, path: tuple, raw: str) -> bytes:
    """`doc` as JSON with the value at `path` replaced by the raw JSON text `raw`."""
    copy = json.loads(json.dumps(doc))
    target = copy
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = "@@RAW@@"
    return json.dumps(copy).replace('"@@RAW@@"', raw).encode()


def _leaves(doc, path=()):
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _leaves(v, path + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _leaves(v, path + (i,))
    else:
        yield path


def _message_edit(topic: str, rng: random.Random, raw: str, every: bool = False, pick=None):
    """An edit of the messages on `topic`: one leaf (chosen by `pick`, else at random) set to `raw`."""
    done: list[int] = []

    def edit(t: str, data: bytes) -> bytes:
        if t != topic or (done and not every):
            return data
        doc = json.loads(data)
        leaves = [p for p in _leaves(doc) if p]
        if pick is not None:
            leaves = [p for p in leaves if pick(p, doc)]
        if not leaves:
            return data
        done.append(1)
        return _raw(doc, rng.choice(leaves), raw)
    return edit


def _relabel(label: str):
    def edit(topic: str, data: bytes) -> bytes:
        if topic != "/events":
            return data
        doc = json.loads(data)
        if doc.get("step_unit") in ("P01", "T1-P01"):
            doc["step_unit"] = label
            step = doc.get("data", {}).get("step")
            if isinstance(step, dict):
                step["unit"] = label
        return json.dumps(doc).encode()
    return edit


def _dated(key: str, value: str):
    return lambda name, data: {**data, key: value} if name == "run" else data


def _can_times(value: float):
    seen: list[int] = []

    def edit(topic: str, data: bytes) -> bytes:
        if topic != "/can/raw" or len(seen) >= 3:
            return data
        seen.append(1)
        return ms.can_frames(20, 8, 0x100, value)
    return edit


def _long_text(topic: str, field: str, size: int, count: int = 60):
    """The first `count` messages' `field` on `topic` made `size` bytes long (UTF-8, two bytes a character)."""
    done: list[int] = []

    def edit(t: str, data: bytes) -> bytes:
        if t != topic or len(done) >= count:
            return data
        doc = json.loads(data)
        if field not in doc:
            return data
        doc[field] = "é" * (size // 2)
        done.append(1)
        return json.dumps(doc, ensure_ascii=False).encode()
    return edit


def make_logs(base: Path, thermal: Path, out: Path, rng: random.Random, n_random: int) -> list[tuple[str, Path]]:
    """(generator, log) pairs."""
    logs: list[tuple[str, Path]] = []

    def add(kind: str, name: str, src: Path, **edits) -> None:
        path = out / f"{kind}-{name}.mcap"
        ms.rewrite(src, path, **edits)
        logs.append((kind, path))

    for k, label in enumerate(LABELS):
        add("labels", f"{k}", thermal if k % 2 else base, message=_relabel(label))
    for k, date in enumerate(DATES):
        add("dates", f"started-{k}", base, metadata=_dated("started_utc", date))
        add("dates", f"finished-{k}", thermal, metadata=_dated("finished_utc", date))
    def thermal_step(p: tuple, d: dict) -> bool:
        step = d.get("data", {}).get("step") if d.get("kind") == "step_started" else None
        return (isinstance(step, dict) and step.get("kind") in ("set_temperature", "soak")
                and p[-1] in ("temperature_index", "setpoint_c", "rate_c_per_min", "stable_min"))

    for k, raw in enumerate(NUMBERS):
        kind = "nan" if "NaN" in raw or "Infinity" in raw else "huge-numbers"
        add(kind, f"thermal-step-{k}", thermal, message=_message_edit("/events", rng, raw, True, thermal_step))
        add(kind, f"chamber-{k}", thermal, message=_message_edit("/chamber/state", rng, raw, True))
        add(kind, f"table-state-{k}", base, message=_message_edit("/table/state", rng, raw))
        add(kind, f"event-{k}", base, message=_message_edit("/events", rng, raw))
    for k, value in enumerate((float("nan"), 1e300, -1e300, float("inf"), -1.0)):
        add("nan" if value != value else "huge-numbers", f"can-time-{k}", base, message=_can_times(value))
    for topic in ("/events", "/chamber/state", "/table/state"):
        add("deep-nesting", topic.strip("/").replace("/", "-"), thermal, message=_message_edit(topic, rng, DEEP))
    for topic, field in (("/chamber/state", "alarm_text"), ("/table/state", "fault_text"), ("/events", "step_unit")):
        add("1mb-text", f"{topic.strip('/').replace('/', '-')}-{field}", thermal,
            message=_long_text(topic, field, 1 << 20))
    for k in range(n_random):   # random leaves of random topics set to random hostile values
        topic = rng.choice(("/events", "/chamber/state", "/table/state"))
        raw = rng.choice(NUMBERS + (DEEP, json.dumps(rng.choice(LABELS)), json.dumps(rng.choice(DATES)), "null",
                                    "{}", "[]", "true", '"x"'))
        add("random", f"{k:03d}", thermal, message=_message_edit(topic, rng, raw, rng.random() < 0.3))
    return logs


def make_json_files(result: Path, noise: Path, out: Path, rng: random.Random, n: int) -> list[tuple[str, str, Path]]:
    """(generator, which, file) for result, noise and table-check files with hostile values."""
    docs = {"result": json.loads(result.read_text(encoding="utf-8")),
            "noise": json.loads(noise.read_text(encoding="utf-8")),
            "check": {"format": "turntable-bench/table-check", "correlation": [[1.0, 0.0], [0.0, 1.0]],
                      "combinations": [{"coefficients": {"alpha_o": 1.0}, "value_arcsec": 12.0, "sigma_arcsec": 0.5},
                                       {"coefficients": {"beta_o": 1.0}, "value_arcsec": -3.0, "sigma_arcsec": 0.5}]}}
    files = []
    for k in range(n):
        which = ("result", "noise", "check")[k % 3]
        raw = rng.choice(NUMBERS + (DEEP,))
        kind = "deep-nesting" if raw == DEEP else "nan" if "NaN" in raw or "Infinity" in raw else "huge-numbers"
        path = out / f"{kind}-{which}-{k:03d}.json"
        path.write_bytes(_raw(docs[which], rng.choice(list(_leaves(docs[which]))), raw))
        files.append((kind, which, path))
    return files


def _config(folder: Path, which: str, path: Path) -> Path:
    from tests.helpers.run import config_text

    text = config_text()
    if which == "noise":
        text = text.replace("rate_hz = ", f'noise = "{path}"\nrate_hz = ', 1)
    elif which == "check":
        text = text.replace('dialect = "scpi"', f'dialect = "scpi"\ncheck = "{path}"', 1)
    else:
        text += f'\n[acceptance]\nreference = "{path}"\n'
    config = folder / f"{path.stem}.toml"
    config.write_text(text, encoding="utf-8")
    return config


# -- running ---------------------------------------------------------------------------------------------------

def run_one(code: Path, argv: list[str], cwd: Path, timeout_s: float, as_limit: int) -> dict:
    env = {**os.environ, "PYTHONPATH": str(code), "MPLBACKEND": "Agg"}   # BENCH_DB: set by main, in --out
    err_path = cwd / f".stderr-{os.getpid()}-{time.monotonic_ns()}"
    with open(err_path, "wb") as err:
        returncode, hung, usage, wall_s = run_limited([sys.executable, "-m", "bench.cli", *argv], cwd, env,
                                                      subprocess.DEVNULL, err, timeout_s, as_limit)
    stderr = err_path.read_text(encoding="utf-8", errors="replace")
    err_path.unlink()
    lines = stderr.strip().splitlines()
    crash = "Traceback (most recent call last)" in stderr or returncode < 0
    return {"rc": returncode, "hang": hung, "crash": crash and not hung, "s": round(wall_s, 2),
            "rss_mb": round(usage.ru_maxrss / 1024), "last": lines[-1][:300] if lines else ""}


def jobs_for(base: Path, thermal: Path, result: Path, logs, json_files, out: Path) -> list[tuple[str, str, list[str]]]:
    """(generator, what, argv) for every input."""
    work = out / "work"
    work.mkdir(exist_ok=True)
    jobs: list[tuple[str, str, list[str]]] = []
    for kind, log in logs:
        jobs.append((kind, f"solve {log.name}", ["solve", str(log), "--out", str(work), "--quiet"]))
        jobs.append((kind, f"replay {log.name}", ["replay", str(log), "--quiet"]))
        if kind in ("huge-numbers", "nan") and "can-time" in log.name:
            for suffix in (".asc", ".blf"):
                jobs.append((kind, f"export-can {log.name} {suffix}",
                             ["export-can", str(log), "--out", str(work / f"{log.stem}{suffix}")]))
    configs = out / "configs"
    configs.mkdir(exist_ok=True)
    for kind, which, path in json_files:
        jobs.append((kind, f"run --dry-run [{which}] {path.name}",
                     ["run", "--config", str(_config(configs, which, path)), "--dry-run", "--no-db"]))
        if which == "result":
            jobs.append((kind, f"export {path.name}", ["export", str(path), "--out", str(work / "x.h")]))
            jobs.append((kind, f"solve --against {path.name}",
                         ["solve", str(base), "--against", str(path), "--out", str(work), "--quiet", "--no-db"]))
            jobs.append((kind, f"check-table --calibration {path.name}",
                         ["check-table", "--log", str(base), "--calibration", str(path), "--out", str(work)]))
            jobs.append((kind, f"noise --calibration {path.name}",
                         ["noise", str(base), "--calibration", str(path), "--out", str(work)]))
            jobs.append((kind, f"apply {path.name}", ["apply", str(path), str(base), "--out", str(work / "x.csv")]))
    specials = out / "specials"
    specials.mkdir(exist_ok=True)
    fifo = specials / "fifo.mcap"
    if not fifo.exists():
        os.mkfifo(fifo)
    sock_path = specials / "socket.mcap"
    if not sock_path.exists():
        sock = socket.socket(socket.AF_UNIX)
        sock.bind(str(sock_path))
        sock.close()
    config = specials / "bench.toml"
    from tests.helpers.run import config_text
    config.write_text(config_text(), encoding="utf-8")
    for special in (fifo, Path("/dev/zero"), specials, sock_path):
        name = special.name or str(special)
        for what, argv in (
                ("solve", ["solve", str(special), "--out", str(work)]),
                ("replay", ["replay", str(special), "--quiet"]),
                ("noise", ["noise", str(special), "--out", str(work)]),
                ("export-can", ["export-can", str(special), "--out", str(work / "x.asc")]),
                ("apply LOG", ["apply", str(result), str(special), "--out", str(work / "x.csv")]),
                ("apply RESULT", ["apply", str(special), str(base), "--out", str(work / "x.csv")]),
                ("export", ["export", str(special), "--out", str(work / "x.json")]),
                ("solve --against", ["solve", str(base), "--against", str(special), "--out", str(work)]),
                ("check-table --log", ["check-table", "--log", str(special), "--out", str(work)]),
                ("check-table --calibration", ["check-table", "--log", str(base), "--calibration", str(special),
                                               "--out", str(work)]),
                ("noise --calibration", ["noise", str(base), "--calibration", str(special), "--out", str(work)]),
                ("thermal eval", ["thermal", "eval", str(special), "--temperature-c", "25"]),
                ("run --resume", ["run", "--config", str(config), "--sim", "--resume", str(special), "--out",
                                  str(work), "--quiet", "--no-db"])):
            jobs.append(("non-regular", f"{what} {name}", argv))
    alias = specials / "alias.mcap"
    if not alias.exists():
        os.link(base, alias)
    other = specials / "other_run.mcap"
    other.write_bytes(thermal.read_bytes())
    copy = specials / "cal.result.json"
    copy.write_bytes(result.read_bytes())
    jobs += [("outputs", "apply --out a hard link to LOG", ["apply", str(result), str(base), "--out", str(alias)]),
             ("outputs", "apply --out another run's log", ["apply", str(result), str(base), "--out", str(other)]),
             ("outputs", "export RESULT --out RESULT", ["export", str(copy), "--out", str(copy), "--format", "json"]),
             ("outputs", "export-can --out another run's log",
              ["export-can", str(base), "--out", str(specials / "other_run.asc")])]
    (specials / "other_run.asc").write_bytes(thermal.read_bytes())
    return jobs


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--code", type=Path, default=REPO, help="the checkout to run (default: this one)")
    ap.add_argument("--base", type=Path, help="a short run's log (default: record one)")
    ap.add_argument("--thermal", type=Path, help="a thermal run's log (default: record one)")
    ap.add_argument("--random", type=int, default=60, help="random hostile log messages")
    ap.add_argument("--json-files", type=int, default=30, help="hostile result/noise/table-check files")
    ap.add_argument("--seed", type=int, default=34)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--timeout-s", type=float, default=120.0)
    ap.add_argument("--as-limit-gib", type=float, default=4.0)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="hostile-files-"))
    out.mkdir(parents=True, exist_ok=True)
    os.environ["BENCH_DB"] = str(out / "records.sqlite")   # the runs record here, never in the user's database
    rng = random.Random(args.seed)
    from tests.helpers.run import record_short_run, record_thermal_run

    base = args.base or record_short_run(out / "base")[0]
    thermal = args.thermal or record_thermal_run(out / "thermal")
    result = next(base.parent.glob("*.result.json"))
    noise = out / "noise"
    if not any(noise.glob("*.noise.json")):
        subprocess.run([sys.executable, "-m", "bench.cli", "noise", "--sim", "--duration-h", "0.05", "--rate-hz", "100",
                        "--out", str(noise), "--quiet"], check=True, cwd=REPO,
                       env={**os.environ, "PYTHONPATH": str(args.code)})
    (out / "logs").mkdir(exist_ok=True)
    (out / "files").mkdir(exist_ok=True)
    logs = make_logs(base, thermal, out / "logs", rng, args.random)
    files = make_json_files(result, next(noise.glob("*.noise.json")), out / "files", rng, args.json_files)
    jobs = jobs_for(base, thermal, result, logs, files, out)
    print(f"{len(jobs)} runs ({len(logs)} logs, {len(files)} JSON files, non-regular files, outputs); inputs in {out}",
          flush=True)
    as_limit = int(args.as_limit_gib * GiB)

    def one(job):
        kind, what, argv = job
        record = {"generator": kind, "what": what, **run_one(args.code, argv, out, args.timeout_s, as_limit)}
        flag = " HANG" if record["hang"] else " CRASH" if record["crash"] else ""
        print(f"{kind}: {what[:90]}: rc={record['rc']} {record['s']} s {record['rss_mb']} MB{flag} "
              f"{record['last'][:120]}", flush=True)
        return record

    with ThreadPoolExecutor(args.jobs) as pool:
        records = list(pool.map(one, jobs))
    if args.json:
        args.json.write_text(json.dumps(records, indent=1), encoding="utf-8")
    print("\n| generator | runs | tracebacks | hangs | worst RSS | worst time |")
    print("|---|---|---|---|---|---|")
    for kind in sorted({r["generator"] for r in records}) + ["all"]:
        mine = [r for r in records if kind in ("all", r["generator"])]
        rss, slow = max(mine, key=lambda r: r["rss_mb"]), max(mine, key=lambda r: r["s"])
        print(f"| {kind} | {len(mine)} | {sum(r['crash'] for r in mine)} | {sum(r['hang'] for r in mine)} | "
              f"{rss['rss_mb']} MB ({rss['what'][:50]}) | {slow['s']} s ({slow['what'][:50]}) |")
    for r in records:
        if r["crash"] or r["hang"]:
            print(f"  {'HANG' if r['hang'] else 'CRASH'} {r['generator']}: {r['what'][:100]}: {r['last'][:200]}")
    return 1 if any(r["crash"] or r["hang"] for r in records) else 0


if __name__ == "__main__":
    sys.exit(main())
