"""Recordings shared by the unit tests of several packages, recorded once per session and only read (see
tests/conftest.py: a test copies a file to its `tmp_path` before it changes it)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest

from tests.helpers.shared import recorded_once, share

#: The recorder of `noisy_run` closes a log chunk every this many seconds of run clock (simulated time), so its log
#: (~240 s simulated) has ~50 chunks of events and frames (and as many of /imu/samples) whatever the machine's
#: speed: the damage tests of tests/unit/solve cut and corrupt single chunks, the report's plots span many.
NOISY_CHUNK_RUN_S = 5.0


@pytest.fixture(scope="session")
def noisy_run(tmp_path_factory) -> SimpleNamespace:
    """`bench run --config` of the short test plan (optimal-24 + optimal-5s6r) with noise on, a 20" black box, 2 s
    dwells at 50 Hz, seed 2: `config`, `text` (its TOML), `out` (the run's folder), `log`, `result_path`, `result`
    (parsed), `report_md`, `report_html`. Shared by the solve and report tests; read only."""
    from tests.helpers.run import cli, config_text, load_json, only_file

    text = (config_text(noise="true", seed=2, black_box_arcsec=20.0, dwell_s=2.0, rate_hz=50.0)
            + f"[output]\nchunk_run_interval_s = {NOISY_CHUNK_RUN_S}\n")

    def record(folder: Path) -> None:
        config = folder / "bench.toml"
        config.write_text(text, encoding="utf-8")
        with pytest.MonkeyPatch.context() as patch:   # a database of its own, as every test has
            patch.setenv("BENCH_DB", str(tmp_path_factory.mktemp("noisy-records") / "records.sqlite"))
            rc, _, stderr = cli(["run", "--config", str(config), "--out", str(folder / "out"), "--quiet"])
        assert rc == 0, stderr

    folder, _ = recorded_once(tmp_path_factory, "noisy", record)
    out = folder / "out"
    result_path = only_file(out, "*.result.json")
    share(folder)
    return SimpleNamespace(config=folder / "bench.toml", text=text, out=out, log=only_file(out, "*.mcap"),
                           result_path=result_path, result=load_json(result_path),
                           report_md=only_file(out, "*.report.md"), report_html=only_file(out, "*.report.html"))
