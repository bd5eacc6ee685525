"""The JSON Schemas of docs/reference/schemas validate what the bench writes: the result of `bench run --sim` and
of `bench run --config`, a calibration over temperature (its thermal file and its per-temperature results),
`bench noise`, `bench check-table`, `bench export` (a result's compensation, a thermal model) and a verification;
and they refuse a document that breaks them (a schema that accepts everything would pass the first half)."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest

jsonschema = pytest.importorskip("jsonschema", reason="the test extra installs jsonschema")

from tests.helpers.run import cli, config_text, only_file  # noqa: E402
from tests.unit.table_check.test_table_check import _schedule_text  # noqa: E402

SCHEMAS = Path(__file__).resolve().parents[2] / "docs" / "reference" / "schemas"


def validator(name: str):
    schema = json.loads((SCHEMAS / f"{name}.schema.json").read_text(encoding="utf-8"))
    jsonschema.Draft202012Validator.check_schema(schema)
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    return jsonschema.Draft202012Validator(schema)


def load(path: Path) -> dict:
    return json.loads(path.read_text(encoding="utf-8"))


def assert_valid(name: str, path: Path) -> dict:
    document = load(path)
    errors = [f"{'/'.join(map(str, e.absolute_path))}: {e.message}" for e in validator(name).iter_errors(document)]
    assert errors == [], f"{path.name} breaks {name}.schema.json: {errors[:5]}"
    return document


def assert_refused(name: str, document: dict) -> None:
    assert list(validator(name).iter_errors(document)), f"{name}.schema.json accepts a broken document"


@pytest.fixture(scope="module")
def noise_file(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("noise")
    rc, _, stderr = cli(["noise", "--sim", "--duration-h", "0.01", "--rate-hz", "100", "--out", str(out)])
    assert rc == 0, stderr
    return only_file(out, "*.noise.json")


@pytest.fixture(scope="module")
def check_file(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("check")
    schedule = out / "table-check-16.toml"       # 16 positions: the shipped 324 take minutes on a loaded machine
    schedule.write_text(_schedule_text((0, 90, 180, 270), (45, 135, 225, 315)), encoding="utf-8")
    rc, _, stderr = cli(["check-table", "--sim", "--schedule", str(schedule), "--dwell-s", "1", "--out",
                         str(out / "out"), "--quiet", "--no-db"])
    assert rc == 0, stderr
    return only_file(out / "out", "*.table-check.json")


def test_every_schema_has_a_page_and_every_page_a_schema():
    from bench.cli.schema_pages import schema_pages

    names = {path.name.removesuffix(".schema.json") for path in SCHEMAS.glob("*.schema.json")}
    assert names == {"result", "thermal", "noise", "table-check", "compensation", "thermal-model-export",
                     "verification"}
    assert {Path(page).stem for page in schema_pages()} == names


def test_the_result_of_a_simulated_run_is_valid(short_run):
    document = assert_valid("result", short_run.result)
    broken = copy.deepcopy(document)
    broken["coefficients"]["Kg_q"] = broken["coefficients"].pop("Kg_x")      # not a canonical name
    assert_refused("result", broken)
    broken = copy.deepcopy(document)
    broken["verdict"]["verdict"] = "maybe"
    assert_refused("result", broken)
    broken = copy.deepcopy(document)
    del broken["coefficients"]["D0_z"]["sigma"]
    assert_refused("result", broken)
    assert_refused("result", {**document, "extra_section": {}})


def test_the_result_of_a_configured_run_is_valid(cli_run_log):
    assert_valid("result", only_file(cli_run_log.parent, "*.result.json"))


def test_a_thermal_run_writes_valid_files(thermal_run_log, tmp_path):
    folder = thermal_run_log.parent
    document = assert_valid("thermal", only_file(folder, "*.thermal.json"))
    for result in folder.glob("*.result.json"):          # the run's result and each temperature's
        assert_valid("result", result)
    broken = copy.deepcopy(document)
    broken["thermal_model"]["coefficients"]["Kg_x"]["degree"] = 7
    assert_refused("thermal", broken)
    exported = tmp_path / "thermal-export.json"
    rc, _, stderr = cli(["export", "--out", str(exported), str(only_file(folder, "*.thermal.json"))])
    assert rc == 0, stderr
    assert_valid("thermal-model-export", exported)


def test_bench_noise_writes_a_valid_file(noise_file):
    document = assert_valid("noise", noise_file)
    broken = copy.deepcopy(document)
    del broken["channels"]["acc_z"]
    assert_refused("noise", broken)


def test_bench_check_table_writes_a_valid_file(check_file):
    document = assert_valid("table-check", check_file)
    assert_refused("table-check", {**document, "combinations": "level_alpha"})


def test_bench_export_writes_a_valid_compensation(short_run, tmp_path):
    exported = tmp_path / "compensation.json"
    rc, _, stderr = cli(["export", "--out", str(exported), str(short_run.result)])
    assert rc == 0, stderr
    document = assert_valid("compensation", exported)
    broken = copy.deepcopy(document)
    broken["gyro"]["matrix"] = broken["gyro"]["matrix"][:2]
    assert_refused("compensation", broken)


def test_a_run_with_a_verification_plan_writes_valid_files(tmp_path):
    text = config_text(dwell_s=1.0).replace("[plan]\n", '[plan]\nverification = "verify-default"\n')
    (tmp_path / "bench.toml").write_text(text, encoding="utf-8")
    rc, _, stderr = cli(["run", "--config", str(tmp_path / "bench.toml"), "--out", str(tmp_path / "out"), "--quiet",
                         "--no-db"])
    assert rc == 0, stderr
    assert_valid("result", only_file(tmp_path / "out", "*.result.json"))
    document = assert_valid("verification", only_file(tmp_path / "out", "*.verify.json"))
    broken = copy.deepcopy(document)
    broken["errors"][0]["unit"] = "furlongs"
    assert_refused("verification", broken)
