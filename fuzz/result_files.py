"""Fuzz `bench db import` with hostile result files (issue 34 item 5), in a subprocess under limits.

Not collected by pytest (the crafted cases are tests/unit/records/test_records_import.py). Writes a real result
file (the in-memory simulated acquisition and the solver) and `--inputs` mutated copies: a field
anywhere in it replaced by a hostile value (10**400, 5,000-digit integers, 1e999, NaN, dates out of
range, labels such as `T²-P01`, 1 MB texts, nesting 100 or 100,000 deep, wrong types), plus a FIFO,
/dev/zero and a 17 MiB file named as result files. A child process imports each file alone
(`bench.cli.main.main(["db", "import", ...])`) under a 4 GiB address-space limit and a timeout, and
reports per file its exit code, whether an exception escaped (a crash), its time; then the whole
folder is imported at once (one bad file must not stop the others). Prints inputs, crashes, hangs,
the worst time and the peak RSS.

    python fuzz/result_files.py [--inputs 300] [--seed 34] [--timeout-s 120] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import random
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

HOSTILE: list[str] = [
    "1" + "0" * 400, "7" * 5000, "-" + "9" * 4300, "1e999", "-1e999", "NaN", "Infinity", "1e-400", "true", "null",
    '"0001-01-01T00:00:00+05:00"', '"9999-12-31T23:59:59-05:00"', '"2026-02-30T00:00:00Z"', '"T\\u00b2-P01"',
    '"' + "T" + "5" * 5000 + '"', '"' + "x" * (1 << 20) + '"', '"\\u0000\\n\\r"', "[" * 100 + "]" * 100,
    "[" * 100_000 + "]" * 100_000, '{"a": ' * 200 + "1" + "}" * 200, "[]", "{}", '""', "-0",
    "123456789012345678901234567890",
]

_CHILD = r"""
import contextlib, io, json, sys, time, traceback
from bench.cli.main import main
db, files = sys.argv[1], json.loads(sys.argv[2])
out = []
for path in files + [None]:
    argv = ["db", "import", "--db", db, "--quiet", path if path is not None else sys.argv[3]]
    start = time.perf_counter()
    err = io.StringIO()
    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
            rc = main(argv)
        crash = None
    except BaseException as exc:   # what the fuzzer counts: anything that escaped the command
        rc, crash = None, traceback.format_exc(limit=3)
    out.append({"path": path, "rc": rc, "crash": crash, "lines": len(err.getvalue().splitlines()),
                "s": time.perf_counter() - start})
print(json.dumps(out))
"""


def mutated(template: str, rng: random.Random) -> str:
    """The template with one JSON value (after a random `": `) replaced by a hostile one."""
    starts = [k + 3 for k in range(len(template) - 3) if template[k:k + 3] == '": ']
    start = rng.choice(starts)
    end = start
    depth, in_text = 0, False
    while end < len(template):                       # the end of that value: a plain scan (the template is ours)
        ch = template[end]
        if in_text:
            in_text = ch != '"' or template[end - 1] == "\\"
        elif ch == '"':
            in_text = True
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            if depth == 0:
                break
            depth -= 1
        elif ch == "," and depth == 0:
            break
        end += 1
    return template[:start] + rng.choice(HOSTILE) + template[end:]


def limit_memory() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (4 << 30, 4 << 30))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--inputs", type=int, default=300)
    parser.add_argument("--seed", type=int, default=34)
    parser.add_argument("--timeout-s", type=float, default=120.0)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="fuzz-results-"))
    folder = out / "in"
    folder.mkdir(parents=True, exist_ok=True)
    import datetime as dt

    from tests.helpers.records import write_result

    good = write_result(out / "good", "FUZZ-1", dt.datetime(2025, 1, 1), seed=1)
    template = good.read_text()
    rng = random.Random(args.seed)
    files = []
    for k in range(args.inputs):
        path = folder / f"m{k:04d}.result.json"
        path.write_text(mutated(template, rng))
        files.append(str(path))
    fifo = folder / "fifo.result.json"
    if not fifo.exists():
        os.mkfifo(fifo)
    big = folder / "big.result.json"
    with open(big, "wb") as f:
        f.truncate(17 << 20)
    files += [str(fifo), "/dev/zero", str(big)]
    child = subprocess.run(["/usr/bin/time", "-f", "%M", sys.executable, "-c", _CHILD, str(out / "r.sqlite"),
                            json.dumps(files), str(folder)], cwd=REPO, capture_output=True, text=True,
                           timeout=args.timeout_s * (len(files) + 1), preexec_fn=limit_memory)
    if child.returncode != 0:
        print(child.stderr[-3000:])
        raise SystemExit(f"the child failed: exit {child.returncode}")
    rows = json.loads(child.stdout.strip().splitlines()[-1])
    peak_mb = int(child.stderr.strip().splitlines()[-1]) / 1024
    crashes = [r for r in rows if r["crash"]]
    slow = max(rows, key=lambda r: r["s"])
    multi = [r for r in rows[:-1] if r["rc"] not in (0, None) and r["lines"] != 1]
    print(f"inputs {len(rows) - 1} files + the whole folder; crashes {len(crashes)}; hangs 0 (all finished); "
          f"errors not one line {len(multi)}; "
          f"recorded alone {sum(r['rc'] == 0 for r in rows[:-1])}, refused {sum(r['rc'] == 4 for r in rows[:-1])}; "
          f"folder import exit {rows[-1]['rc']}; worst time {slow['s']:.2f} s ({slow['path']}); "
          f"peak RSS {peak_mb:.0f} MB")
    for r in crashes[:5]:
        print(f"CRASH {r['path']}:\n{r['crash']}")
    if crashes or multi:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
