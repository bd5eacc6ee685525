"""No private name crosses a module boundary (issue 28, item 6).

A name with a leading underscore is its module's own: another module that needs it gets it made
public (renamed) or moved to where it is used. `bench`, `drivers` and `schedules` are read with
`ast`: `from x import _name` (relative imports resolved), and `x._name` where `x` is bound to one of
our modules (`import a.b as x`, `from a import b`, `import a.b` then `a.b._name`), fail with the
file, line and name. Dunder names (`__version__`) are not private. Attribute use on anything else
(`self._x`, an object's `_x`) is not a module boundary and is not looked at.
"""

from __future__ import annotations

import ast
import textwrap
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ("bench", "drivers", "schedules")


def _module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _is_private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _absolute(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    """The module a `from ... import` reads from, relative levels resolved."""
    if not node.level:
        return node.module or ""
    package = module.split(".") if is_package else module.split(".")[:-1]
    package = package[:len(package) - node.level + 1]
    return ".".join(package + ([node.module] if node.module else []))


def crossings(module: str, is_package: bool, source: str, modules: set[str]) -> list[tuple[int, str]]:
    """(line, what) of every private name `module` takes from another of `modules`."""
    tree = ast.parse(source)
    found: list[tuple[int, str]] = []
    bound: dict[str, str] = {}     # local name -> one of our modules it is bound to
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            origin = _absolute(module, is_package, node)
            for alias in node.names:
                if f"{origin}.{alias.name}" in modules:      # a submodule, not a name in it
                    bound[alias.asname or alias.name] = f"{origin}.{alias.name}"
                elif _is_private(alias.name) and origin != module:
                    found.append((node.lineno, f"from {origin} import {alias.name}"))
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.asname:
                    bound[alias.asname] = alias.name
                else:
                    top = alias.name.split(".")[0]
                    bound[top] = top
    for node in ast.walk(tree):
        if not (isinstance(node, ast.Attribute) and _is_private(node.attr)):
            continue
        chain, value = [], node.value
        while isinstance(value, ast.Attribute):
            chain.append(value.attr)
            value = value.value
        if not (isinstance(value, ast.Name) and value.id in bound):
            continue
        owner = ".".join([bound[value.id], *reversed(chain)])
        if owner in modules and owner != module:
            found.append((node.lineno, f"{owner}.{node.attr}"))
    return sorted(found)


def _ours(root: Path) -> dict[str, Path]:
    return {_module_name(p, root): p for pkg in PACKAGES for p in sorted((root / pkg).rglob("*.py"))}


def test_no_private_name_is_imported_across_modules():
    modules = _ours(REPO)
    known = set(modules)
    bad = [f"{path.relative_to(REPO)}:{line}: {what}"
           for name, path in modules.items()
           for line, what in crossings(name, path.name == "__init__.py", path.read_text(encoding="utf-8"), known)]
    assert not bad, "private names used outside their module (make them public or move them):\n" + "\n".join(bad)


MODULES = {"pkg", "pkg.a", "pkg.b", "pkg.sub", "pkg.sub.c"}


@pytest.mark.parametrize("source, expected", [
    ("from pkg.b import _helper", ["from pkg.b import _helper"]),
    ("from .b import public, _helper as h", ["from pkg.b import _helper"]),
    ("from .sub.c import _X", ["from pkg.sub.c import _X"]),
    ("from pkg import b\nb._helper()", ["pkg.b._helper"]),
    ("import pkg.sub.c as c\nc._X", ["pkg.sub.c._X"]),
    ("import pkg.b\npkg.b._helper", ["pkg.b._helper"]),
    ("def f():\n    from pkg.b import _late\n    return _late", ["from pkg.b import _late"]),
    ("from . import _in_init", ["from pkg import _in_init"]),   # the package's __init__ is another module
])
def test_the_check_finds_each_form(source, expected):
    assert [what for _, what in crossings("pkg.a", False, textwrap.dedent(source), MODULES)] == expected


@pytest.mark.parametrize("source", [
    "from pkg.b import helper, __version__",
    "from pkg.a import _own",                 # its own module
    "self._cache = 1\nobj._field",
    "import numpy as np\nnp._NoValue",        # not ours
    "from pkg import b\nb.public._inner",     # an attribute of an object in b, not of the module
])
def test_the_check_lets_these_pass(source):
    assert crossings("pkg.a", False, source, MODULES) == []
