"""What the log reader makes of damaged logs, written down so that two code trees can be compared (issue 28, item 5).

Not collected by pytest. `make` writes the inputs once: the small logs of tests/unit/log/test_log_fuzz.py (zstd, lz4,
none) with `--count` random mutations (tests/helpers/mcap_surgery.py, from `--seed`), plus a few crafted ones
(refused chunks in a row, a chunk over the cap, a decompression bomb, a deferred chunk that fails its CRC).
`read` reads every input with the code tree it runs from (`--code ROOT`: through PYTHONPATH) in three ways
(the default, `defer_samples=False`, `messages=False`) and writes, per input, everything a caller sees: the
damage lines in order (found on reading, then after the states, samples and frames are read), the damage
entries' fields, counts, hashes of the arrays, the one-line summary, or the `LogError` line. `compare` says
which inputs differ.

    python fuzz/reader_fingerprints.py make --out DIR [--count 400] [--seed 28]
    python fuzz/reader_fingerprints.py read --in DIR --code ROOT --json FILE
    python fuzz/reader_fingerprints.py compare A.json B.json
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import random
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def make(out: Path, count: int, seed: int) -> None:
    sys.path.insert(0, str(REPO))
    from tests.helpers import mcap_surgery as ms
    from tests.unit.log.test_log_fuzz import base_log

    out.mkdir(parents=True, exist_ok=True)
    rng = random.Random(seed)
    for compression in ("zstd", "lz4", "none"):
        base = base_log(compression)
        (out / f"base-{compression}.mcap").write_bytes(base)
        for k in range(count):
            data = base
            for _ in range(rng.randint(1, 3)):
                kind = rng.choice(ms.KINDS)
                value = rng.choice(ms.FORGED) if rng.random() < 0.5 else rng.randrange(1 << 64)
                flips = [(rng.random(), rng.randint(1, 255)) for _ in range(rng.randint(1, 6))]
                data = ms.mutate(data, kind, rng.random(), value, flips)
            (out / f"mut-{compression}-{k:04d}.mcap").write_bytes(data)
        positions = ms.chunks(base)
        msg = ms.message_record(1, ms.can_frames(40))
        crafted = {
            "over-cap": ms.chunk_record(msg * 10, "", 1 << 40),
            "declared-100": ms.chunk_record(msg * 10, "", 100),
            "zstd-bomb-declared-4k": ms.chunk_record(ms.zstd_bomb(msg, 64 << 20, content_size=False), "zstd", 4096),
            "zstd-bomb-1g": ms.chunk_record(ms.zstd_bomb(msg, (1 << 30) - (1 << 30) % len(msg)), "zstd",
                                            (1 << 30) - (1 << 30) % len(msg)),
        }
        for name, chunk in crafted.items():
            data = base
            for pos in reversed(positions[1:4]):   # three in a row: refusals for one reason are told as one
                data = ms.replace_chunk(data, pos, chunk)
            (out / f"crafted-{compression}-{name}.mcap").write_bytes(data)
        for k, pos in enumerate(positions):   # each chunk's CRC broken in turn (deferred ones included)
            f = ms.chunk_fields(base, pos)
            if f["crc"]:
                data = bytearray(base)
                data[f["usize_at"] + 8] ^= 0xFF
                (out / f"crc-{compression}-{k:02d}.mcap").write_bytes(bytes(data))


def _digest(*arrays) -> str:
    import numpy as np

    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(np.asarray(a))
        h.update(str((a.dtype.str, a.shape)).encode())
        h.update(a.tobytes() if a.dtype != object else repr(a.tolist()).encode())
    return h.hexdigest()[:16]


def _damage_now(log) -> tuple[list[str], list]:
    """The damage lines and entries with every chunk looked at (the API of either code tree)."""
    if hasattr(log, "scan"):
        scan = log.scan()
        return list(scan.damage), list(scan.lost)
    return list(log.damage), list(log.lost)


def _read(log, method: str, attribute: str):
    """`log.method()`, or the property it replaced (issue 28 item 5: I/O in properties made explicit)."""
    return getattr(log, method)() if hasattr(log, method) else getattr(log, attribute)


def _found(log) -> list[str]:
    return list(log.damage_found)


def _fingerprint(path: Path, **kwargs) -> dict:
    try:
        from bench.log.reader import LogError, read_log
    except ImportError:   # after the move
        from bench.log.mcap import LogError, read_log  # type: ignore[no-redef]
    try:
        log = read_log(path, **kwargs)
    except LogError as exc:
        return {"error": str(exc).replace(str(path), "<path>")}
    out: dict = {"found_on_read": _found(log), "counts": log.message_counts, "chunks": log.chunks,
                 "summary_present": log.summary_present, "library": log.library,
                 "metadata": log.metadata, "attachments": sorted(log.attachments),
                 "summary_found": log.summary(read_frames=False).replace(str(path), "<path>"),
                 "unchecked": log.unchecked_chunks}
    states = _read(log, "read_table_states", "table_states")
    out["states"] = [len(states), _digest(states.time_s, states.angles_deg, states.rates_dps, states.status,
                                          states.estop), repr(states.modes)[:2000], repr(states.fault_text)[:2000]]
    out["events"] = [repr(e)[:300] for e in log.events]
    out["chamber"] = len(log.chamber_states)
    out["found_after_states"] = _found(log)
    records = _read(log, "read_imu_records", "imu_records")
    out["records"] = [len(records), _digest(records.counter, records.imu_time_s, records.receive_time_s,
                                            records.gyro_counts, records.acc_counts, records.temperature_c,
                                            records.status)]
    block, stats = log.imu_samples()
    out["samples"] = [len(block.counter), _digest(block.counter, block.gyro_counts, block.acc_counts),
                      repr(stats)[:2000]]
    damage, lost = _damage_now(log)
    out["damage"] = damage
    out["lost"] = [[d.kind, d.offset, d.reason, d.start_ns, d.end_ns, d.lost, d.chunks, d.last_offset] for d in lost]
    scan = log.scan() if hasattr(log, "scan") else log
    out["frames"] = [scan.can_frame_count, scan.non_data_frames]
    out["timestamps"] = _digest(_read(log, "read_can_timestamps_s", "can_timestamp_s"))
    out["summary"] = log.summary().replace(str(path), "<path>")
    return out


def read(inputs: Path, code: Path, json_out: Path) -> None:
    if os.environ.get("_FINGERPRINT_CHILD") != "1":
        env = dict(os.environ, PYTHONPATH=str(code), _FINGERPRINT_CHILD="1")
        subprocess.run([sys.executable, __file__, "read", "--in", str(inputs), "--code", str(code),
                        "--json", str(json_out)], check=True, cwd=code, env=env)
        return
    result: dict = {}
    for path in sorted(inputs.glob("*.mcap")):
        per: dict = {}
        for name, kwargs in (("default", {}), ("not_deferred", {"defer_samples": False}),
                             ("no_messages", {"messages": False})):
            try:
                per[name] = _fingerprint(path, **kwargs)
            except Exception as exc:   # a bug: written down as one, compared like the rest
                per[name] = {"bug": f"{type(exc).__name__}: {exc}"}
        result[path.name] = per
    json_out.write_text(json.dumps(result, indent=1, sort_keys=True, default=str), encoding="utf-8")
    damaged = sum(1 for v in result.values() if v["default"].get("damage") or v["default"].get("error"))
    reasons = {line for v in result.values() for line in v["default"].get("damage", [])}
    bugs = sum(1 for v in result.values() for m in v.values() if "bug" in m)
    print(f"{len(result)} inputs, {damaged} damaged or refused, {len(reasons)} distinct damage lines, {bugs} bugs")


def compare(a: Path, b: Path) -> int:
    left, right = (json.loads(p.read_text(encoding="utf-8")) for p in (a, b))
    differ = sorted(k for k in left.keys() | right.keys() if left.get(k) != right.get(k))
    for name in differ[:20]:
        for mode in ("default", "not_deferred", "no_messages"):
            x, y = (left.get(name) or {}).get(mode, {}), (right.get(name) or {}).get(mode, {})
            keys = sorted(k for k in x.keys() | y.keys() if x.get(k) != y.get(k))
            if keys:
                print(f"{name} [{mode}]: {', '.join(keys)}")
                for k in keys[:3]:
                    print(f"  - {str(x.get(k))[:300]}\n  + {str(y.get(k))[:300]}")
    print(f"{len(left)} and {len(right)} inputs; {len(differ)} differ")
    return 1 if differ else 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("make")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--count", type=int, default=400)
    p.add_argument("--seed", type=int, default=28)
    p = sub.add_parser("read")
    p.add_argument("--in", dest="inputs", type=Path, required=True)
    p.add_argument("--code", type=Path, default=REPO)
    p.add_argument("--json", type=Path, required=True)
    p = sub.add_parser("compare")
    p.add_argument("a", type=Path)
    p.add_argument("b", type=Path)
    args = parser.parse_args()
    if args.command == "make":
        make(args.out, args.count, args.seed)
        return 0
    if args.command == "read":
        read(args.inputs, args.code.resolve(), args.json.resolve())
        return 0
    return compare(args.a, args.b)


if __name__ == "__main__":
    raise SystemExit(main())
