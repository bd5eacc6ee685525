"""A simulated static-noise log written as a run writes it, fast (no sequencer, no wall clock).

For the tests of `bench noise LOG` and the `benchmarks/noise_speed.py` benchmark: metadata,
the dwell's `step_started` / `step_finished` events and the raw CAN frames of the simulated IMU
(quantised counts, the configured layout), in batches of 100 samples per `/can/raw` message as the
recorder gets them live (its chunks close every 5 s of run clock). `drop` takes whole samples' frames out
(counter gaps); `/imu/samples` is not written (a noise read never opens it).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np


def write_static_log(path: Path, seconds: float, rate_hz: float, layout_name: str = "packed",
                     drop: tuple[tuple[int, int], ...] = (), seed: int = 0) -> Path:
    """Write the log to `path` (via a `.partial` file); `drop`: [start, stop) sample ranges left out."""
    from bench.config.load import parse_config
    from bench.log.events import make_event
    from bench.log.format import record_dtype
    from bench.log.recorder import McapRecorder
    from bench.model.earth import Site
    from bench.plan.steps import DwellStep, step_to_dict
    from bench.run.runner import compile_from_config
    from bench.sim.imu import SimImu
    from bench.sim.table import SimTable
    from drivers.imu import ImuEncoder

    text = f"""format = "turntable-bench/config"
version = 1
[site]
latitude_deg = 30.27
[table]
url = "sim"
dialect = "scpi"
[imu]
interface = "virtual"
channel = "static-log"
rate_hz = {rate_hz}
layout = "{layout_name}"
[plan]
positions = "static-noise"
dwell_s = {seconds}
[sim]
seed = {seed}
"""
    path = Path(path)
    config = parse_config(text, source=str(path.with_suffix(".toml")))
    dwell = next(s for s in compile_from_config(config).steps if isinstance(s, DwellStep))
    layout = config.imu.layout
    encoder = ImuEncoder(layout)
    imu = SimImu(config.sim.imu, config.sim.noise, rate_hz=rate_hz, seed=seed)
    table = SimTable(Site(latitude_deg=30.27))
    n_total = int(round(seconds * rate_hz))
    tmp = path.with_suffix(".partial")
    metadata = {"run": {"run_id": path.stem, "mode": "simulator"},
                "config": {"toml": text, "path": "<tests/helpers/static_log.py>"},
                "imu": {"model": "simulated FOG IMU", "serial": "SIM-0001", "rate_hz": str(rate_hz),
                        "interface": "virtual", "channel": "static-log", "dbc": config.imu.dbc.name}}
    dtype = record_dtype(("data", "u1", (8,)))
    per = len(layout.messages)
    per_batch = 100 * per                        # frames per /can/raw message
    with McapRecorder(str(tmp), metadata=metadata) as rec:
        rec.on_event(make_event(0.0, "step_started", "P01 dwell", step_index=dwell.index, step_unit="P01",
                           data={"step": step_to_dict(dwell)}))
        done, t_end = 0, 0.0
        while done < n_total:
            t_end = min(t_end + 600.0, n_total / rate_hz)
            block = imu.generate(table, t_end)
            frames = encoder.encode(block.counter, block.gyro_counts, block.acc_counts)
            records = np.zeros(len(frames), dtype=dtype)
            records["t"] = block.time_s[frames.sample] + (np.arange(len(frames)) % per) * 1e-6
            records["id"] = frames.ids
            records["len"] = frames.lengths
            records["data"] = frames.data
            if drop:
                sample = frames.sample + done
                keep = np.ones(len(frames), bool)
                for a, b in drop:
                    keep &= ~((sample >= a) & (sample < b))
                records = records[keep]
            for lo in range(0, len(records), per_batch):
                batch = records[lo:lo + per_batch]
                rec.on_encoded_can_frames(batch.tobytes(), len(batch), float(batch["t"][-1]))
            done += len(block)
        rec.on_event(make_event(t_end, "step_finished", "P01 dwell done", step_index=dwell.index, step_unit="P01",
                           data={"step": step_to_dict(dwell), "counter_first": 0, "counter_last": n_total - 1,
                                 "samples": n_total}))
    os.replace(tmp, path)
    return path


__all__ = ["write_static_log"]
