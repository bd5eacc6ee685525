"""The layout's rules, checked on the source (docs/explanation/architecture.md, "Code map").

The import rules are import-linter contracts in pyproject.toml (`[tool.importlinter]`): bench's
layers, no cycle between sibling packages or modules of bench, drivers and schedules importing
no bench, only bench.tui importing textual, nothing below bench.cli importing it. The graph
they are checked on counts function-local imports and imports under `if TYPE_CHECKING:`.
Here they are run as `lint-imports` runs them, each is shown to catch the import it forbids,
and the graph is shown to hold every import the source has. What import-linter does not
check (a function-local import says why; the layers that cannot import each other agree on
the frame names) is checked on the source with `ast`.
"""

from __future__ import annotations

import ast
import copy
import subprocess
import sys
from pathlib import Path

import grimp
import pytest
from importlinter.api import read_configuration
from importlinter.contracts.acyclic_siblings import AcyclicSiblingsContract
from importlinter.contracts.forbidden import ForbiddenContract
from importlinter.contracts.layers import LayersContract

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ("bench", "drivers", "schedules")
CONTRACT_TYPES = {"layers": LayersContract, "forbidden": ForbiddenContract, "acyclic_siblings": AcyclicSiblingsContract}

#: (contract id, an import that breaks it) for every contract in pyproject.toml
BREAKING_IMPORTS = {
    "layers": ("bench.model.units", "bench.solve.methods"),
    "acyclic": ("bench.plan.steps", "bench.plan.compiler"),
    "no-bench-below": ("drivers.clock", "bench.errors"),
    "schedules-alone": ("schedules.loader", "drivers.clock"),
    "textual-in-tui": ("bench.run.runner", "textual"),
    "cli-on-top": ("bench.report.html", "bench.cli.common"),
}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _sources() -> dict[str, tuple[Path, ast.Module]]:
    return {_module_name(p): (p, ast.parse(p.read_text(encoding="utf-8")))
            for pkg in PACKAGES for p in sorted((REPO / pkg).rglob("*.py"))}


@pytest.fixture(scope="module")
def sources() -> dict[str, tuple[Path, ast.Module]]:
    return _sources()


@pytest.fixture(scope="module")
def options() -> dict:
    return read_configuration(str(REPO / "pyproject.toml"))


@pytest.fixture(scope="module")
def graph(options) -> grimp.ImportGraph:
    session = options["session_options"]
    assert str(session.get("exclude_type_checking_imports", False)).lower() != "true"
    return grimp.build_graph(*session["root_packages"], include_external_packages=True, cache_dir=None)


def _contract(options: dict, contract_id: str):
    found = [c for c in options["contracts_options"] if c.get("id") == contract_id]
    assert len(found) == 1, f"no contract {contract_id!r} in pyproject.toml"
    return CONTRACT_TYPES[found[0]["type"]](name=found[0]["name"], session_options=options["session_options"],
                                             contract_options=found[0])


def test_lint_imports_keeps_every_contract():
    # what CI runs: the command line tool on the configuration in pyproject.toml
    done = subprocess.run([sys.executable, "-c", "from importlinter.cli import lint_imports_command as c; c()",
                           "--config", "pyproject.toml", "--no-cache"],
                          cwd=REPO, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    assert f"Contracts: {len(BREAKING_IMPORTS)} kept, 0 broken." in done.stdout


def test_every_contract_has_a_breaking_import_here(options):
    assert {c["id"] for c in options["contracts_options"]} == set(BREAKING_IMPORTS)


@pytest.mark.parametrize("contract_id", sorted(BREAKING_IMPORTS))
def test_each_contract_catches_the_import_it_forbids(options, graph, contract_id):
    contract = _contract(options, contract_id)
    assert contract.check(copy.deepcopy(graph), verbose=False).kept
    importer, imported = BREAKING_IMPORTS[contract_id]
    broken = copy.deepcopy(graph)
    broken.add_import(importer=importer, imported=imported, line_number=1, line_contents=f"import {imported}")
    assert not contract.check(broken, verbose=False).kept


@pytest.mark.parametrize("contract_id, owner", [("textual-in-tui", "bench.tui"), ("cli-on-top", "bench.cli")])
def test_only_the_owner_is_left_out_of_a_forbidden_contract(options, contract_id, owner):
    # a new package of bench is under the rule without anyone remembering to add it
    packages = {f"bench.{p.stem if p.is_file() else p.name}" for p in (REPO / "bench").iterdir()
                if (p.is_dir() and (p / "__init__.py").exists()) or (p.suffix == ".py" and p.stem != "__init__")}
    contract = next(c for c in options["contracts_options"] if c["id"] == contract_id)
    assert set(contract["source_modules"]) == packages - {owner} | {"drivers", "schedules"}


def _imports(tree: ast.Module, name: str, path: Path):
    """(statement, imported first-party or top-level third-party module) for every import in `tree`."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            yield from ((node, a.name) for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
                package = package[:len(package) - node.level + 1]
                base = ".".join(package + ([base] if base else []))
            yield node, base


def test_the_graph_holds_every_import_of_the_source_local_and_type_only_included(sources, graph):
    missing = []
    for name, (path, tree) in sources.items():
        for node, target in _imports(tree, name, path):
            if target.split(".")[0] in PACKAGES:
                # `from package import module` is an import of the module, `from module import name` of the module
                candidates = {target} | {f"{target}.{a.name}" for a in getattr(node, "names", [])}
                if not any(t in graph.modules and graph.direct_import_exists(importer=name, imported=t)
                           for t in candidates):
                    missing.append(f"{name} -> {target} ({path.relative_to(REPO)}:{node.lineno})")
    assert not missing, "imports the contracts' graph does not see:\n" + "\n".join(missing)


def _function_local_imports(tree: ast.Module):
    """The import statements inside a function, each with the body it stands in."""
    for function in ast.walk(tree):
        if isinstance(function, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for owner in ast.walk(function):
                for field in ("body", "orelse", "finalbody", "handlers"):
                    body = getattr(owner, field, None)
                    if isinstance(body, list):
                        for k, stmt in enumerate(body):
                            if isinstance(stmt, (ast.Import, ast.ImportFrom)):
                                yield body, k, stmt


def test_function_local_imports_say_why(sources):
    bad = []
    for name, (path, tree) in sources.items():
        lines = path.read_text(encoding="utf-8").splitlines()
        seen = set()
        for body, k, stmt in _function_local_imports(tree):
            if id(stmt) in seen:        # a nested function's import is seen from each enclosing one
                continue
            seen.add(id(stmt))
            first = k
            while first > 0 and isinstance(body[first - 1], (ast.Import, ast.ImportFrom)):
                first -= 1              # the comment may stand above the group of imports
            above = lines[body[first].lineno - 2].strip() if body[first].lineno >= 2 else ""
            if not above.startswith("#") and "#" not in lines[stmt.end_lineno - 1]:
                bad.append(f"{name} ({path.relative_to(REPO)}:{stmt.lineno})")
    assert not bad, ("function-local imports without a comment saying why (an optional or heavy dependency, "
                     "or the CLI's start-up time):\n" + "\n".join(bad))


def test_frame_names_agree_across_the_layers():
    # drivers and schedules cannot import bench, so each keeps the names; they must be the same
    from bench.model.kinematics import FRAMES
    from drivers.turntable import FRAMES as DRIVER_FRAMES
    from schedules.loader import FRAMES as SCHEDULE_FRAMES

    assert FRAMES == DRIVER_FRAMES == SCHEDULE_FRAMES == ("outer", "middle", "inner")
