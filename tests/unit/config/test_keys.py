"""The configuration key table (bench/config/keys.py) against the loader, its generated page and bench.example.toml.

- every key the loader accepts (every `Table` it builds, while loading configurations that use every section) is
  in the table with a meaning, and every key of the table is accepted somewhere;
- docs/reference/configuration.md is what `python -m bench.cli.docs_gen` writes now;
- bench.example.toml loads, each key it sets has the table's default unless it is a listed override, and each
  default and range its comments state is the table's.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pytest

import bench.config.acceptance as config_acceptance
import bench.config.load as config_load
from bench.config import keys
from bench.config.load import load_config, parse_config
from bench.config.reader import Table
from bench.model.families import canonical_names
from drivers.errors import ImuConfigError
from drivers.imu import ImuFrameSpec

REPO = Path(__file__).resolve().parents[3]
EXAMPLE = REPO / "bench.example.toml"

#: a configuration that builds every section's table (together with the two shipped examples)
EVERY_SECTION = """\
format = "turntable-bench/config"
version = 1
[site]
latitude_deg = 30.0
[table]
url = "sim"
dialect = "scpi"
pointing_accuracy_arcsec = {outer = 3.0, middle = 5.0, inner = 5.0}
[table.limits.outer]
max_rate_dps = 100.0
[imu]
interface = "virtual"
channel = "keys-test"
rate_hz = 100.0
[imu.rig]
id = "1C2B"
[plan]
positions = "optimal-24"
rotations = "optimal-5s6r"
dwell_s = 2.0
temperatures_c = [0.0, 25.0]
[plan.soak]
stable_min = 5.0
[sim.noise]
enabled = true
[sim.imu.thermal]
reference_c = 25.0
[sim.imu.higher_order]
grade = "nav-fog"
[acceptance.Kg]
max_sigma = 1.0
[acceptance.Kg_x]
max_sigma = 1.0
[acceptance.verification]
gyro_bias_dph = 1.0
[chamber]
url = "sim"
[chamber.limits]
min_setpoint_c = -40.0
"""

#: keys the loader reads without a `Table` of their own: the register maps (checked by the drivers' maps,
#: docs/hardware/modbus.md and docs/hardware/chamber.md), the signal mapping (`ImuFrameSpec`, checked below) and the bus
#: options (passed to python-can as given)
NOT_A_TABLE = ("table.modbus", "chamber.modbus", "imu.signals", "imu.bus_options")

#: keys bench.example.toml sets to other than the default, on purpose (an example site, a visible override)
EXAMPLE_OVERRIDES = {
    "site.height_m": "an example site's height",
    "plan.positions": "the plan of the example", "plan.rotations": "the plan of the example",
    "plan.revolutions": "shows the override of the schedule's revolutions",
    "imu.identity.model": "an example IMU", "imu.identity.serial": "an example IMU",
    "imu.signals.gyro_x": "the shipped mapping, written out", "imu.signals.gyro_y": "", "imu.signals.gyro_z": "",
    "imu.signals.acc_x": "", "imu.signals.acc_y": "", "imu.signals.acc_z": "", "imu.signals.temperature": "",
    "imu.signals.status": "",
}


def built_tables(monkeypatch, texts: list[tuple[str, Path]]) -> dict[tuple, tuple[str, ...]]:
    """(path of a table) -> the keys it accepts, for every `Table` the loader builds while loading `texts`."""
    seen: dict[tuple, tuple[str, ...]] = {}
    original = Table.__init__

    def recording(self, doc, path, data, allowed):
        allowed = tuple(allowed)
        seen[tuple(path)] = allowed
        original(self, doc, path, data, allowed)

    monkeypatch.setattr(Table, "__init__", recording)
    for text, base in texts:
        parse_config(text, base_dir=base)
    return seen


def undocumented(tables: dict[tuple, tuple[str, ...]]) -> list[str]:
    """The accepted keys the key table does not declare (or declares without a meaning)."""
    missing = []
    for path, allowed in tables.items():
        if ".".join(str(p) for p in path).startswith(NOT_A_TABLE):
            continue
        for name in allowed:
            entry = keys.match(tuple(path) + (name,))
            if entry is None or not entry.meaning.strip():
                missing.append(".".join(tuple(path) + (name,)))
    return missing


def every_section(monkeypatch) -> dict[tuple, tuple[str, ...]]:
    texts = [(EXAMPLE.read_text(encoding="utf-8"), REPO), ((REPO / "thermal.example.toml").read_text(), REPO),
             ((REPO / "multi-imu.example.toml").read_text(), REPO), (EVERY_SECTION, REPO)]
    return built_tables(monkeypatch, texts)


def test_every_key_the_loader_accepts_is_documented(monkeypatch):
    tables = every_section(monkeypatch)
    assert ("chamber", "limits") in tables and ("sim", "imu", "thermal") in tables  # every section was built
    assert undocumented(tables) == [], "add these keys to bench/config/keys.py KEYS (with their meaning)"


def test_a_key_added_to_the_loader_without_documentation_is_found(monkeypatch):
    monkeypatch.setattr(config_load, "ACCEPTANCE_KEYS", config_acceptance.ACCEPTANCE_KEYS + ("max_new_limit",))
    assert undocumented(every_section(monkeypatch)) == ["acceptance.max_new_limit"]


def test_every_documented_key_is_accepted(monkeypatch):
    tables = every_section(monkeypatch)
    accepted = {tuple(path) + (name,) for path, allowed in tables.items() for name in allowed}
    for entry in keys.KEYS:
        if entry.dotted.startswith(NOT_A_TABLE):
            continue
        assert any(keys.match(path) is entry for path in accepted), f"{entry.dotted} is documented, not accepted"


def test_the_signal_mapping_keys_are_documented():
    with pytest.raises(ImuConfigError) as caught:
        ImuFrameSpec.from_dict({"no_such_key": 1})
    known = re.search(r"known: ([^)]*)\)", str(caught.value)).group(1).split(", ")
    assert sorted(known) == sorted(keys.allowed("imu.signals"))


def test_the_configuration_page_is_current():
    from bench.cli.reference_pages import REGENERATE, configuration_page

    page = REPO / "docs" / "reference" / "configuration.md"
    assert page.is_file() and page.read_text(encoding="utf-8") == configuration_page(), \
        f"docs/reference/configuration.md is stale: run `{REGENERATE}`"
    for entry in keys.KEYS:
        assert f"| `{entry.name}` |" in page.read_text(encoding="utf-8")


# --- bench.example.toml -----------------------------------------------------------------------------------------

def _leaves(table: dict, path: tuple = ()):
    for name, value in table.items():
        entry = keys.match(path + (name,))
        if isinstance(value, dict) and (entry is None or "table" in entry.type) and \
                ".".join(path + (name,)) != "imu.bus_options":
            yield from _leaves(value, path + (name,))
        else:
            yield path + (name,), value


def test_the_example_loads_and_sets_the_defaults_or_a_listed_override():
    load_config(EXAMPLE)
    document = tomllib.loads(EXAMPLE.read_text(encoding="utf-8"))
    for path, value in _leaves(document):
        dotted = ".".join(path)
        if dotted.startswith("imu.bus_options"):
            continue
        entry = keys.match(path)
        assert entry is not None, f"bench.example.toml sets {dotted}, which the key table does not declare"
        if dotted in EXAMPLE_OVERRIDES or entry.default in (keys.REQUIRED, keys.NONE):
            continue
        assert value == entry.default, (f"bench.example.toml sets {dotted} = {value!r}, the table's default is "
                                        f"{entry.default!r}: list it in EXAMPLE_OVERRIDES or set the default")


_SECTION = re.compile(r"^#?\s*\[([\w.]+)\]")
_KEY = re.compile(r"^(?:#\s*)?([A-Za-z_]\w*)\s*=\s*[^#]*#(.*)$")
_CONTINUATION = re.compile(r"^\s{8,}#(.*)$")
_NUMBER = r"-?\d[\d_.]*(?:e[-+]?\d+)?"


def example_comments() -> list[tuple[tuple, str]]:
    """(key path, its comment text with continuation lines) of every key line of bench.example.toml, set or
    commented out."""
    found: list[tuple[tuple, str]] = []
    section: tuple = ()
    for line in EXAMPLE.read_text(encoding="utf-8").splitlines():
        if (head := _SECTION.match(line)) and "=" not in line.split("#")[0 if not line.startswith("#") else 1]:
            section = tuple(head.group(1).split("."))
            continue
        if (more := _CONTINUATION.match(line)) and found:
            found[-1] = (found[-1][0], found[-1][1] + " " + more.group(1).strip())
            continue
        if key_line := _KEY.match(line):
            found.append((section + (key_line.group(1),), key_line.group(2).strip()))
    return found


def _float(text: str) -> float:
    return float(text.replace("_", "").rstrip("."))


def test_the_example_states_the_tables_defaults_and_ranges():
    checked = 0
    for path, comment in example_comments():
        entry = keys.match(path)
        if entry is None:
            continue
        default = re.search(rf"default ({_NUMBER})(?![\w/])", comment)
        if default and entry.default_text is not None:
            stated = {_float(n) for n in re.findall(_NUMBER, entry.default_text)}
            assert _float(default.group(1)) in stated, f"{'.'.join(path)}: the example says default " \
                f"{default.group(1)}, the key table {entry.default_text!r}"
            checked += 1
        elif default and isinstance(entry.default, (int, float)) and not isinstance(entry.default, bool):
            assert _float(default.group(1)) == entry.default, f"{'.'.join(path)}: the example says default " \
                f"{default.group(1)}, the key table {entry.default!r}"
            checked += 1
        span = re.search(rf"(?<![\w.])({_NUMBER})\.\.({_NUMBER})", comment)
        if span and entry.ge is not None and entry.le is not None and entry.range_text is None:
            assert (_float(span.group(1)), _float(span.group(2))) == (entry.ge, entry.le), \
                f"{'.'.join(path)}: the example says {span.group(0)}, the key table {entry.show_range()}"
            checked += 1
        upper = re.search(rf"> 0 and <= ({_NUMBER})", comment)
        if upper and entry.gt == 0 and entry.le is not None and entry.ge is None:
            assert _float(upper.group(1)) == entry.le, f"{'.'.join(path)}: the example says {upper.group(0)}"
            checked += 1
    assert checked >= 40, checked          # the parse found the example's figures


def test_sim_imu_coefficients_match_the_placeholder():
    assert keys.PLACEHOLDERS["<coefficient>"] == tuple(canonical_names())


def test_every_key_the_example_shows_is_declared():
    """Set or commented out, each key line of bench.example.toml names a key of the table (the register maps and
    the bus options excepted, as above)."""
    shown = [path for path, _ in example_comments()]
    assert len(shown) > 100
    undeclared = [".".join(path) for path in shown
                  if keys.match(path) is None and not ".".join(path).startswith(NOT_A_TABLE)]
    assert undeclared == []
