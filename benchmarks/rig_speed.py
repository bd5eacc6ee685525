"""Benchmark: a wall-clock run against `bench sim rig` with the IMU at 2 kHz over SLCAN (issue 14).

Run: python benchmarks/rig_speed.py [--rate-hz 2000] [--layout packed] [--slcan-client bench]
[--imu-listen slcan] [--repeats 3]
Starts `bench sim rig` (SCPI over TCP, the IMU over SLCAN on a pty in the given frame layout, noise on;
read by the bench's bulk SLCAN reader or python-can's `slcan` interface) and `bench run
--config <the written config>` with the short plan (traditional-12 + traditional-3s6r, 1 s
dwells, fast moves and turns) as two processes, in wall-clock time. Reports per run: the
`bench run` process's CPU time per second of run (user + system over wall, target under 25 %
of one core), the samples and frames the run lost (target 0), and the rig's own CPU per
second over the same span (from /proc), each run's and the median over the repeats, with the
machine's load average before and after. The numbers go to the README's Speed section.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import results

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tests.helpers.sim_process import read_until  # noqa: E402
from tests.protocol.test_sim_rig import RIG_CONFIG, SHORT_PLAN, _start_rig, _with_plan  # noqa: E402


def _proc_cpu_s(pid: int) -> float:
    """User + system CPU seconds of a live process, from /proc (Linux)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    ticks = os.sysconf("SC_CLK_TCK")
    return (int(fields[11]) + int(fields[12])) / ticks


def one_run(rate_hz: float, imu_listen: str, layout: str, slcan_client: str) -> dict:
    work = Path(tempfile.mkdtemp(prefix="rig-speed-"))
    rig_config = work / "rig.toml"
    rig_config.write_text(RIG_CONFIG.format(dialect="scpi").replace("rate_hz = 100.0", f"rate_hz = {rate_hz}"))
    written = work / "bench.toml"
    rig = _start_rig("--config", str(rig_config), "--table-listen", "tcp://127.0.0.1:0", "--imu-listen",
                     imu_listen, "--imu-layout", layout, "--write-config", str(written))
    try:
        read_until(rig, "Ctrl-C stops")
        text = _with_plan(written.read_text(), SHORT_PLAN)
        if slcan_client != "bench":
            text = text.replace("[imu]\n", f'[imu]\nslcan_client = "{slcan_client}"\n', 1)
        written.write_text(text)
        out = work / "runs"
        before_children = resource.getrusage(resource.RUSAGE_CHILDREN)
        rig_cpu0, t0 = _proc_cpu_s(rig.pid), time.monotonic()
        run = subprocess.run([sys.executable, "-m", "bench.cli", "run", "--config", str(written), "--out", str(out),
                              "--quiet"], cwd=REPO, capture_output=True, text=True, timeout=300)
        wall_s = time.monotonic() - t0
        rig_cpu_s = _proc_cpu_s(rig.pid) - rig_cpu0
        after_children = resource.getrusage(resource.RUSAGE_CHILDREN)
        run_cpu_s = ((after_children.ru_utime - before_children.ru_utime)
                     + (after_children.ru_stime - before_children.ru_stime))
        if run.returncode != 0:
            return {"wall_s": wall_s, "failed": f"exit {run.returncode}: " + run.stderr.strip()[-300:]}
        result = json.loads(next(out.glob("*.result.json")).read_text())
        link = result["run"]["imu_link"]
        return {"wall_s": wall_s, "run_cpu_per_s": run_cpu_s / wall_s, "rig_cpu_per_s": rig_cpu_s / wall_s,
                "samples": link["samples"], "frames": link["frames"], "lost_samples": link["incomplete_samples"]
                + link["counter_gaps"], "frame_faults": link["crc_errors"] + link["late"] + link["wrong_length"]
                + link["unknown_id"] + link["duplicates"]}
    finally:
        rig.terminate()
        try:
            rig.wait(timeout=10)
        except subprocess.TimeoutExpired:
            rig.kill()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rate-hz", type=float, default=2000.0)
    ap.add_argument("--layout", default="packed", choices=("classic", "packed"))
    ap.add_argument("--slcan-client", default="bench", choices=("bench", "python-can"))
    ap.add_argument("--imu-listen", default="slcan")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    print(f"{args.rate_hz:g} Hz, layout {args.layout}, {args.imu_listen} read by {args.slcan_client}; load average "
          f"before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)
    done = []
    for k in range(args.repeats):
        r = one_run(args.rate_hz, args.imu_listen, args.layout, args.slcan_client)
        if "failed" in r:
            print(f"run {k + 1}: bench run failed after {r['wall_s']:.1f} s: {r['failed']}", flush=True)
            continue
        done.append(r)
        print(f"run {k + 1}: {r['wall_s']:.1f} s wall; bench run CPU {r['run_cpu_per_s']:.1%} of a core "
              f"(target < 25 %), rig CPU {r['rig_cpu_per_s']:.1%}; {r['samples']:,} samples, {r['frames']:,} frames; "
              f"lost samples {r['lost_samples']}, bad frames {r['frame_faults']} (target 0)", flush=True)
    if done:
        def median(key: str) -> float:
            return statistics.median(r[key] for r in done)

        print(f"median of {len(done)}: {median('wall_s'):.1f} s wall; bench run CPU {median('run_cpu_per_s'):.1%}; "
              f"rig CPU {median('rig_cpu_per_s'):.1%}; lost samples (all runs) {sum(r['lost_samples'] for r in done)}, "
              f"bad frames {sum(r['frame_faults'] for r in done)}; load average after: "
              f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)
        path = results.record("rig_speed", medians_s={"bench run against the rig, wall time": median("wall_s")},
                              ratios={"bench run CPU share of one core": median("run_cpu_per_s"),
                                      "rig CPU share of one core": median("rig_cpu_per_s"),
                                      "lost samples, all runs": float(sum(r["lost_samples"] for r in done))},
                              parameters={"rate_hz": args.rate_hz, "layout": args.layout,
                                          "slcan_client": args.slcan_client, "imu_listen": args.imu_listen,
                                          "repeats": args.repeats, "completed": len(done)})
        print(f"figures written to {path}")
    return 0 if len(done) == args.repeats else 1


if __name__ == "__main__":
    sys.exit(main())
