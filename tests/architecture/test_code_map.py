"""The code map (docs/explanation/architecture.md, "Code map") matches the code: every package and top-level
module of bench is in it, in the order of the import-linter layers (bottom first), every module of drivers is
named in its entry, and every path it names exists."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
CODE_MAP_PAGE = REPO / "docs" / "explanation" / "architecture.md"


def code_map() -> list[tuple[str, str]]:
    """(path, description) of each entry of the code map, in order."""
    text = CODE_MAP_PAGE.read_text(encoding="utf-8")
    section = text[text.index("## Code map"):]
    block = re.search(r"```\n(.*?)```", section, re.S)
    assert block, "the code map's block"
    entries: list[tuple[str, str]] = []
    for line in block.group(1).splitlines():
        if line[:1].strip():
            path, _, description = line.partition(" ")
            entries.append((path.rstrip(","), description.strip()))
        elif entries:
            entries[-1] = (entries[-1][0], entries[-1][1] + " " + line.strip())
    return entries


def bench_parts() -> set[str]:
    """bench's packages (nested ones too) as `bench/x/` and its top-level modules as `bench/x.py`."""
    packages = {f"{p.parent.relative_to(REPO).as_posix()}/" for p in (REPO / "bench").rglob("__init__.py")}
    modules = {p.relative_to(REPO).as_posix() for p in (REPO / "bench").glob("*.py") if p.name != "__init__.py"}
    return (packages - {"bench/"}) | modules


def layers() -> list[set[str]]:
    """bench's layers from the import-linter contract, top first: each a set of names (`model`, `files`, ...)."""
    config = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))
    contract = next(c for c in config["tool"]["importlinter"]["contracts"] if c["type"] == "layers")
    return [{name.strip() for name in layer.split("|")} for layer in contract["layers"]]


def test_every_package_and_module_of_bench_is_in_the_code_map():
    listed = {path for path, _ in code_map()}
    missing = sorted(bench_parts() - listed)
    assert not missing, f"not in the code map: {missing}"


def test_every_path_the_code_map_names_exists():
    for path, _ in code_map():
        for part in path.split(","):
            assert (REPO / part.strip()).exists(), f"the code map names {part!r}, which does not exist"


def test_the_code_map_lists_bench_bottom_up_in_the_order_of_its_layers():
    level = {name: k for k, layer in enumerate(layers()) for name in layer}
    order = []
    for path, _ in code_map():
        parts = path.split("/")
        if parts[0] == "bench" and len(parts) >= 2:
            name = parts[1].removesuffix(".py")
            assert name in level, f"{path} is in no layer of the import-linter contract"
            order.append((level[name], path))
    # the map goes up the stack: a later entry is never on a lower layer than an earlier one
    for (below, below_path), (above, above_path) in zip(order, order[1:]):
        assert above <= below, f"the code map lists {above_path} after {below_path}, which is above it"


def test_every_module_of_drivers_is_named_in_its_entry():
    entry = dict(code_map())["drivers/"]
    names = {p.stem for p in (REPO / "drivers").glob("*.py") if p.name != "__init__.py"}
    names |= {p.name for p in (REPO / "drivers").iterdir() if (p / "__init__.py").exists()}
    missing = sorted(name for name in names if not re.search(rf"\b{re.escape(name)}\b", entry))
    assert not missing, f"the code map's drivers/ entry does not name {missing}"
