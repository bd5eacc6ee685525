"""Run `bench solve` and `bench replay --quiet` on hostile run logs, as subprocesses (issue 13, items 6 and 7).

Not collected by pytest (the suite's in-process fuzz test is tests/unit/log/test_log_fuzz.py, the crafted
cases are tests/unit/log/test_log_limits.py). Records a short simulated run (or takes `--base LOG`),
writes crafted logs (decompression bombs in zstd, lz4 and uncompressed chunks, chunks over the
size cap, CAN records claiming 255 data bytes, malformed step events, table angles of 1e308, a
DBC padded with a long comment) and `--random` mutated copies (tests/helpers/mcap_surgery.py:
truncation, byte flips, forged record lengths, chunk sizes, index entries, CAN length bytes,
hostile message content), plus with `--big` seven files of about 1 GB (needs ~7.5 GB in --out).
Each runs with a timeout and an 8 GiB address-space limit; prints per code tree the inputs
tried, crashes (a traceback, or a death by signal), hangs (timeouts), the peak RSS
(`/usr/bin/time`) and the slowest run.

    python fuzz/hostile_logs.py [--code ROOT ...] [--base LOG] [--random 220] [--seed 13] [--big]
                                      [--timeout-s 120] [--out DIR] [--json FILE]

`--code ROOT` runs the bench from another checkout through PYTHONPATH (e.g. `git worktree add
/tmp/before <commit>`); given twice, every input runs against both. Default: this checkout.
Give fixed checkouts (worktrees of commits), not a tree being edited while this runs (an hour
with --big): a run that meets a half-edited file counts its SyntaxError as a crash.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import resource
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from mcap.reader import make_reader  # noqa: E402

from tests.helpers import mcap_surgery as ms  # noqa: E402
from tests.helpers.run import config_text  # noqa: E402

GiB = 1 << 30
AS_LIMIT = 8 * GiB   # a runaway allocation fails instead of taking the machine down


def base_log(out: Path, code: Path) -> Path:
    config = out / "bench.toml"
    config.write_text(config_text(), encoding="utf-8")
    subprocess.run([sys.executable, "-m", "bench.cli", "run", "--config", str(config), "--out", str(out / "run"),
                    "--quiet"], check=True, cwd=out, env=dict(os.environ, PYTHONPATH=str(code)))
    return next((out / "run").glob("*.mcap"))


def _json_edit(topic: str, edit, every: bool = False):
    done: list[int] = []

    def fn(t, data):
        if t != topic or (done and not every):
            return data
        new = edit(json.loads(data))
        if new is None:
            return data
        done.append(1)
        return json.dumps(new).encode()
    return fn


def _first_can(payload: bytes, count: int):
    """The first `count` /can/raw messages replaced by `payload`."""
    seen: list[int] = []

    def fn(topic, data):
        if topic != "/can/raw" or len(seen) >= count:
            return data
        seen.append(1)
        return payload
    return fn


def _finished(kind: str, edit):
    return lambda d: edit(d) if d["kind"] == "step_finished" and d["data"]["step"]["kind"] == kind else None


def crafted(base: Path, out: Path) -> list[Path]:
    buf = base.read_bytes()
    with open(base, "rb") as f:
        summary = make_reader(f).get_summary()
    can = next(cid for cid, c in summary.channels.items() if c.topic == "/can/raw")
    mid = ms.chunks(buf)[len(ms.chunks(buf)) // 2]
    msg = ms.message_record(can, ms.can_frames(40))
    made = []

    def put(name: str, chunk: bytes) -> None:
        made.append(out / f"crafted-{name}.mcap")
        made[-1].write_bytes(ms.replace_chunk(buf, mid, chunk))

    for gib in (1, 4):   # bombs: the size stated in the frame and declared, or declared small
        total = gib * GiB - gib * GiB % len(msg)
        z = ms.zstd_bomb(msg, total)
        put(f"zstd-{gib}g-declared", ms.chunk_record(z, "zstd", total))
        put(f"zstd-{gib}g-declared-4k", ms.chunk_record(z, "zstd", 4096))
    put("zstd-zeros-4g-declared", ms.chunk_record(ms.zstd_bomb(b"\0" * 4096, 4 * GiB), "zstd", 4 * GiB))
    unstated = ms.zstd_bomb(msg, 64 << 20, content_size=False)
    put("zstd-unstated-64m-declared-4k", ms.chunk_record(unstated, "zstd", 4096))
    put("zstd-unstated-64m-declared-2^40", ms.chunk_record(unstated, "zstd", 1 << 40))
    for declared in (1 << 40, (1 << 63) - 1, (1 << 64) - 1):
        put(f"zstd-small-declared-{declared:#x}", ms.chunk_record(ms.zstd_bomb(msg, 10 * len(msg)), "zstd", declared))
    lz = ms.lz4_bomb(msg, GiB - GiB % len(msg))
    put("lz4-1g-declared-4k", ms.chunk_record(lz, "lz4", 4096))
    six = buf
    for pos in reversed(ms.chunks(buf)[10:16]):
        six = ms.replace_chunk(six, pos, ms.chunk_record(lz, "lz4", 4096))
    made.append(out / "crafted-lz4-six-1g-chunks.mcap")
    made[-1].write_bytes(six)
    put("none-declared-2^40", ms.chunk_record(msg * 10, "", 1 << 40))
    put("none-declared-100", ms.chunk_record(msg * 10, "", 100))
    for mib in (200, 257):   # honest, framed by their index: under and over the chunk cap
        n = (mib << 20) // len(msg)
        index = ms.message_index(can, [(1_000_000_000, k * len(msg)) for k in range(n)])
        put(f"zstd-honest-{mib}m-indexed", ms.chunk_record(ms.zstd_bomb(msg, n * len(msg)), "zstd", n * len(msg))
            + index)

    def content(name: str, message=None, attachment=None) -> None:
        made.append(ms.rewrite(base, out / f"crafted-{name}.mcap", message, attachment))

    for name, payload in (("can-len255-one", ms.can_frames(3) + ms.can_frames(1, 255) + ms.can_frames(2)),
                          ("can-len255-all", ms.can_frames(50, 255))):
        content(name, _first_can(payload, 5))
    events = {"step-string": ("dwell", lambda d: {**d, "data": {**d["data"], "step": "dwell"}}),
              "step-list": ("dwell", lambda d: {**d, "data": {**d["data"], "step": ["dwell"]}}),
              "counter-string": ("dwell", lambda d: {**d, "data": {**d["data"], "counter_first": "x"}}),
              "counters-huge": ("dwell", lambda d: {**d, "data": {**d["data"], "counter_first": -10 ** 30}}),
              "unit-list": ("dwell", lambda d: {**d, "step_unit": [d["step_unit"]]}),
              "time-string": ("dwell", lambda d: {**d, "time_s": "soon"}),
              "frame-unknown": ("turn", lambda d: {**d, "data": {**d["data"], "step": {**d["data"]["step"],
                                                                                      "frame": "sideways"}}}),
              "revolutions-string": ("turn", lambda d: {**d, "data": {**d["data"], "step": {**d["data"]["step"],
                                                                                            "revolutions": "two"}}})}
    for name, (kind, edit) in events.items():
        content(f"events-{name}", _json_edit("/events", _finished(kind, edit)))
    for name, every, angles in (("one", False, (1e308, None)), ("all", True, (1e308, -1e308))):
        content(f"angles-1e308-{name}", _json_edit("/table/state", lambda d, a=angles: {
            **d, "angles_deg": [a[0], d["angles_deg"][1] if a[1] is None else a[1], d["angles_deg"][2]]}, every))
    for mib in (2, 20):
        content(f"dbc-comment-{mib}m", attachment=lambda name, data, m=mib: data + b'\nCM_ "' + b"x" * (m << 20)
                + b'";\n' if name.endswith(".dbc") else data)
    return made


def big(base: Path, out: Path) -> list[Path]:
    """About 1 GB each: what a file of that size can make the reader do."""
    buf = base.read_bytes()
    with open(base, "rb") as f:
        ids = {c.topic: cid for cid, c in make_reader(f).get_summary().channels.items()}
    positions = ms.chunks(buf)
    head, body = buf[:positions[1]], buf[positions[1]:positions[-1]]
    msg = ms.message_record(ids["/can/raw"], ms.can_frames(40))
    n256, n4 = (256 << 20) // len(msg) - 1, (4 << 20) // len(msg)
    honest = (ms.chunk_record(ms.zstd_bomb(msg, n256 * len(msg)), "zstd", n256 * len(msg))
              + ms.message_index(ids["/can/raw"], [(1_000_000_000, k * len(msg)) for k in range(n256)]))
    bomb4 = ms.chunk_record(ms.zstd_bomb(msg, n4 * len(msg)), "zstd", n4 * len(msg))
    states = ms.message_record(ids["/table/state"], b"{}")
    mixed = ms.message_record(ids["/can/raw"], (ms.can_frames(1, 8) + ms.can_frames(1, 0)) * 20)
    tiny = struct.pack("<BQI", 15, 4, 0)
    files = {
        "big-honest-256m-chunks-1g": (honest, GiB // len(honest)),
        "big-4m-bomb-chunks-1g": (bomb4, GiB // len(bomb4)),
        "big-repeated-real-1g": (body, GiB // len(body)),
        "big-chunk-opcodes-1g": (b"\x06" * (64 << 20), 16),
        "big-tiny-records-1g": (tiny * ((64 << 20) // len(tiny)), 16),
        "big-tiny-state-messages-1g": (ms.chunk_record(states * ((200 << 20) // len(states)), "",
                                                       (200 << 20) // len(states) * len(states)), 5),
        "big-mixed-can-1g": (ms.chunk_record(mixed * ((200 << 20) // len(mixed)), "",
                                             (200 << 20) // len(mixed) * len(mixed)), 5),
    }
    made = []
    for name, (block, count) in files.items():
        made.append(out / f"{name}.mcap")
        with open(made[-1], "wb") as f:
            f.write(head)
            for _ in range(count):
                f.write(block)
    return made


def _limit() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (AS_LIMIT, AS_LIMIT))


def run_one(code: Path, argv: list[str], timeout_s: float, cwd: Path) -> dict:
    cmd = ["/usr/bin/time", "-f", "MAXRSS_KB=%M", sys.executable, "-m", "bench.cli", *argv]
    env = dict(os.environ, PYTHONPATH=str(code), MPLBACKEND="Agg")
    t0 = time.monotonic()
    try:
        p = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout_s, preexec_fn=_limit)
    except subprocess.TimeoutExpired:
        return {"rc": None, "hang": True, "crash": False, "s": timeout_s, "rss_mb": None, "last": ""}
    rss = [int(line.split("=")[1]) / 1024 for line in p.stderr.splitlines() if line.startswith("MAXRSS_KB=")]
    lines = [line for line in p.stderr.splitlines() if not line.startswith(("MAXRSS_KB=", "Command "))]
    crash = "Traceback (most recent call last)" in p.stderr or "terminated by signal" in p.stderr
    return {"rc": p.returncode, "hang": False, "crash": crash, "s": round(time.monotonic() - t0, 2),
            "rss_mb": round(rss[0]) if rss else None, "last": lines[-1][:300] if lines else ""}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--code", type=Path, action="append", help="a checkout to run (repeatable; default: this one)")
    ap.add_argument("--base", type=Path, help="the log to craft from (default: record a short simulated run)")
    ap.add_argument("--random", type=int, default=220)
    ap.add_argument("--seed", type=int, default=13)
    ap.add_argument("--big", action="store_true", help="add seven files of about 1 GB")
    ap.add_argument("--timeout-s", type=float, default=120.0)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    codes = args.code or [REPO]
    out = args.out or Path(tempfile.mkdtemp(prefix="hostile-logs-"))
    (out / "logs").mkdir(parents=True, exist_ok=True)
    base = args.base or base_log(out, codes[-1])
    logs = [out / "logs" / "base.mcap"]
    logs[0].write_bytes(base.read_bytes())
    logs += crafted(base, out / "logs")
    rng, data = random.Random(args.seed), base.read_bytes()
    for k in range(args.random):
        mutated = data
        for _ in range(rng.randint(1, 3)):
            value = rng.choice(ms.FORGED + (rng.getrandbits(64),))
            flips = [(rng.random(), rng.randint(1, 255)) for _ in range(rng.randint(1, 6))]
            mutated = ms.mutate(mutated, rng.choice(ms.KINDS), rng.random(), value, flips)
        logs.append(out / "logs" / f"random-{k:03d}.mcap")
        logs[-1].write_bytes(mutated)
    if args.big:
        logs += big(base, out / "logs")
    results: dict[str, dict] = {}
    for code in codes:
        work = out / "work" / code.name
        work.mkdir(parents=True, exist_ok=True)
        for log in logs:
            for cmd, argv in (("solve", ["solve", str(log), "--out", str(work)]),
                              ("replay", ["replay", str(log), "--quiet"])):
                r = run_one(code, argv, args.timeout_s, work)
                results[f"{code} {cmd} {log.name}"] = r
                flag = " HANG" if r["hang"] else (" CRASH" if r["crash"] else "")
                print(f"{code.name} {cmd} {log.name}: rc={r['rc']} {r['s']} s {r['rss_mb']} MB{flag} {r['last'][:120]}",
                      flush=True)
    print(f"\n{len(logs)} inputs ({len(logs) - 1 - args.random - 7 * args.big} crafted, {args.random} random"
          f"{', 7 of ~1 GB' if args.big else ''}), each through bench solve and bench replay --quiet:")
    print("| code | runs | crashes | hangs | peak RSS | slowest |")
    print("|---|---|---|---|---|---|")
    for code in codes:
        mine = {" ".join(k.split(" ", 2)[:0:-1]): v for k, v in results.items() if k.startswith(f"{code} ")}
        worst = max(mine.items(), key=lambda kv: kv[1]["rss_mb"] or 0)
        slow = max(mine.items(), key=lambda kv: kv[1]["s"])
        print(f"| {code} | {len(mine)} | {sum(v['crash'] for v in mine.values())} | "
              f"{sum(v['hang'] for v in mine.values())} | {worst[1]['rss_mb']} MB ({worst[0]}) | "
              f"{slow[1]['s']} s ({slow[0]}) |")
    if args.json:
        args.json.write_text(json.dumps(results, indent=1), encoding="utf-8")
    print(f"inputs and outputs in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
