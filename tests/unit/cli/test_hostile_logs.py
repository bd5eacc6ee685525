"""A log from outside is hostile (issue 13, items 5 and 12): names read from a log never become paths
outside `--out`, and free text from a log is escaped in the Markdown reports.

Two real logs are recorded on the simulator and shared: a short calibration run (optimal-24 +
optimal-5s6r, 1 s dwells) and a 16-position table check (1 s dwells) run by an operator named
`<script>`. The crafted logs are copies with rewritten metadata or an extra attachment
(`tests/helpers/crafted.py`, written with the `mcap` library).
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import pytest

from bench.errors import InputError
from bench.log.names import BENCH_RUN_ID, fallback_name, output_path, run_id_of, safe_name, sibling_log
from bench.log.reader import read_log
from drivers.imu import DEFAULT_DBC
from tests.helpers.crafted import rewrite_log
from tests.helpers.run import cli, config_text, only_file

SCRIPT = "<script>alert(1)</script>"


def _schedule_text() -> str:
    lines = ['format = "turntable-bench/schedule"', "version = 1", 'name = "table-check-16"', 'kind = "table-check"',
             'description = "short table check for tests"', ""]
    for o in (0, 90, 180, 270):
        for i in (45, 135, 225, 315):
            lines += ["[[position]]", f"angles_deg = [{o}, 0, {i}]", ""]
    return "\n".join(lines)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory, cli_run_log):
    folder = tmp_path_factory.mktemp("hostile")
    schedule = folder / "table-check-16.toml"
    schedule.write_text(_schedule_text(), encoding="utf-8")
    check_config = folder / "check.toml"
    check_config.write_text(config_text(noise="true", black_box_arcsec=20.0), encoding="utf-8")
    rc, _, stderr = cli(["check-table", "--config", str(check_config), "--schedule", str(schedule), "--dwell-s", "1",
                         "--out", str(folder / "check"), "--quiet", "--operator", SCRIPT])
    assert rc == 0, stderr
    return SimpleNamespace(folder=folder, log=cli_run_log,
                           check_log=only_file(folder / "check", "*.mcap"),
                           check_json=json.loads(only_file(folder / "check", "*.table-check.json").read_text()),
                           check_md=only_file(folder / "check", "*.table-check.md").read_text(encoding="utf-8"),
                           check_html=only_file(folder / "check", "*.table-check.html").read_text(encoding="utf-8"))


def _craft(src: Path, folder: Path, name: str = "crafted.mcap", **changes) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    return rewrite_log(src, folder / name, **changes)


def _files(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


def _no_traceback(stderr: str) -> None:
    assert "Traceback" not in stderr and len(stderr.strip().splitlines()) <= 1, stderr


# -- the helper ----------------------------------------------------------------------------------------

def test_safe_names_and_the_fallback():
    assert safe_name("20261123T204354Z-aa1b50") and BENCH_RUN_ID.fullmatch("20261123T204354Z-aa1b50")
    for bad in ("..", ".", "../../escape", "/etc/passwd", "a/b", "a\\b", "a\x00b", ".hidden", "", "x" * 101,
                "caf\u00e9", "a b", None, 7):
        assert safe_name(bad) is None, bad
    assert fallback_name("/some/where/../../we ird\x00name.mcap") == "we-ird-name"
    assert fallback_name("/x/....mcap") == "log"
    assert run_id_of("/x/a.mcap", {"run": {"run_id": "../../escape"}}) == (
        "a", 'the log\'s run id "../../escape" is not a safe file name: outputs are named after the log file (a)')
    assert run_id_of("/x/a.mcap", {}) == ("a", None)
    with pytest.raises(InputError):
        output_path("/out", "../x.json")
    assert output_path("/out", "r.optimal-24+optimal-5s6r.result.json") == Path("/out/r.optimal-24+optimal-5s6r"
                                                                                 ".result.json")
    assert sibling_log("/runs/b.mcap", "/elsewhere/a.mcap") == (Path("/runs/a.mcap"), "")
    for bad in ("/etc/passwd", "../x", "..", ".mcap", "a\x00.mcap", 3, "b.mcap"):
        path, why = sibling_log("/runs/b.mcap", bad)
        assert path is None and "skipped" in why and "\n" not in why and "\x00" not in why, bad


def test_the_bench_makes_run_ids_of_its_own_format(recorded):
    run_id = read_log(recorded.log).metadata["run"]["run_id"]
    assert BENCH_RUN_ID.fullmatch(run_id) and safe_name(run_id) == run_id


# -- bench solve ---------------------------------------------------------------------------------------

@pytest.mark.slow
@pytest.mark.parametrize("run_id, label", [("../../escape", "dots"), ("a\x00b", "nul"),
                                           ("<img src=x onerror=alert(1)>", "html")])
def test_solve_names_outputs_after_the_log_when_its_run_id_is_not_safe(recorded, tmp_path, run_id, label):
    crafted = _craft(recorded.log, tmp_path / "deep" / "er" / "logs", metadata={"run": {"run_id": run_id}})
    out = tmp_path / "deep" / "er" / "out"
    before = _files(tmp_path)
    rc, stdout, stderr = cli(["solve", str(crafted), "--out", str(out)])
    assert rc == 0, stderr
    _no_traceback(stderr)
    new = _files(tmp_path) - before
    assert new and all(name.startswith("deep/er/out") for name in new), new     # nothing outside --out
    assert {Path(n).name for n in new} - {"out"} == {f"crafted.solved.{s}" for s in
                                                     ("result.json", "report.md", "report.html")}
    note = next(line for line in stdout.splitlines() if "is not a safe file name" in line)
    assert note.startswith("note: crafted.mcap: the log's run id ") and "(crafted)" in note
    result = json.loads((out / "crafted.solved.result.json").read_text())
    assert result["run"]["run_id"] == "crafted"
    md = (out / "crafted.solved.report.md").read_text(encoding="utf-8")
    assert "<img" not in md and "\x00" not in md


@pytest.mark.slow
def test_solve_skips_logs_before_entries_that_are_not_sibling_logs(recorded, tmp_path):
    entries = ["/etc/passwd", "../x", "..", "sub/../../../etc/shadow.mcap"]
    crafted = _craft(recorded.log, tmp_path / "logs", metadata={"run": {"logs_before": json.dumps(entries)}})
    rc, stdout, stderr = cli(["solve", str(crafted), "--out", str(tmp_path / "out"), "--no-html"])
    assert rc == 0, stderr
    _no_traceback(stderr)
    notes = [line for line in stdout.splitlines() if line.startswith("note: ")]
    for entry in ("/etc/passwd", "../x", '".."'):
        assert any(entry in n and "skipped" in n for n in notes), (entry, notes)
    # a .mcap base name is only ever looked for next to the log
    assert any("shadow.mcap, which is not found next to it" in n for n in notes), notes
    assert all("\n" not in n for n in notes)
    run_id = read_log(recorded.log).metadata["run"]["run_id"]
    assert _files(tmp_path / "out") == {f"{run_id}.solved.result.json", f"{run_id}.solved.report.md"}
    for malformed in ("[", "{}", '"a"'):
        crafted = _craft(recorded.log, tmp_path / "m", metadata={"run": {"logs_before": malformed}})
        rc, stdout, stderr = cli(["solve", str(crafted), "--out", str(tmp_path / "m-out"), "--no-html"])
        assert rc == 0 and "is not a JSON list: ignored" in stdout, (malformed, stdout, stderr)


def test_an_attachment_named_dot_dot_is_not_written_anywhere(recorded, tmp_path):
    log = read_log(recorded.log)
    toml = log.metadata["config"]["toml"].replace('[imu.identity]', 'dbc = "/nowhere-here/.."\n[imu.identity]')
    assert toml != log.metadata["config"]["toml"]
    crafted = _craft(recorded.log, tmp_path / "logs",
                     metadata={"config": {"toml": toml}, "imu": {"dbc": ".."}},
                     attachments={"..": DEFAULT_DBC.read_bytes()})
    rc, stdout, stderr = cli(["solve", str(crafted), "--out", str(tmp_path / "out"), "--no-html"])
    _no_traceback(stderr)
    assert rc == 0, stderr
    assert 'the attachment ".." is not a safe file name: not used' in stdout
    run_id = log.metadata["run"]["run_id"]
    assert _files(tmp_path) == {"logs", "logs/crafted.mcap", "out", f"out/{run_id}.solved.result.json",
                                f"out/{run_id}.solved.report.md"}


# -- bench check-table --log ----------------------------------------------------------------------------

def test_check_table_outputs_stay_in_out_and_the_run_id_is_checked(recorded, tmp_path):
    crafted = _craft(recorded.check_log, tmp_path / "a" / "b" / "logs", name="check.mcap",
                     metadata={"run": {"run_id": "../../escape"}})
    out = tmp_path / "a" / "b" / "out"
    before = _files(tmp_path)
    rc, stdout, stderr = cli(["check-table", "--log", str(crafted), "--out", str(out)])
    assert rc == 0, stderr
    _no_traceback(stderr)
    new = _files(tmp_path) - before
    assert all(name.startswith("a/b/out") for name in new), new
    assert {Path(n).name for n in new} - {"out"} == {f"check.table-check{s}" for s in
                                                     (".json", ".md", ".html", "-curves.svg", "-map.svg")}
    assert any(line.startswith("note: the log's run id \"../../escape\" is not a safe file name")
               for line in stdout.splitlines()), stdout
    assert json.loads((out / "check.table-check.json").read_text())["run"]["run_id"] == "check"


def test_the_table_check_records_the_operator_escaped(recorded):
    assert recorded.check_json["run"]["operator"] == SCRIPT
    assert "<script" not in recorded.check_md and "- operator: &lt;script&gt;alert(1)&lt;/script&gt;" in \
        recorded.check_md
    assert "<script" not in recorded.check_html
    assert "<tr><th>operator</th><td>&lt;script&gt;alert(1)&lt;/script&gt;</td></tr>" in recorded.check_html
