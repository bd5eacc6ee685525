"""The pages docs/reference/schemas/<name>.md: one per JSON Schema docs/reference/schemas/<name>.schema.json.

The schemas are written by hand (what a file may hold is a decision, not a dump of one run) and the tests
validate what the bench writes against them (tests/e2e/test_schemas.py); these pages list each schema's
properties from the schema itself, so the page and the schema cannot disagree.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Callable
from pathlib import Path

from bench.cli.reference_pages import HEADER, REPO, cell

SCHEMA_DIR = REPO / "docs" / "reference" / "schemas"


def _type(schema: dict) -> str:
    if "const" in schema:
        return f"`{json.dumps(schema['const'])}`"
    if "enum" in schema:
        return " or ".join(f"`{json.dumps(v)}`" for v in schema["enum"])
    if "$ref" in schema:
        name = schema["$ref"].rsplit("/", 1)[-1]
        return f"[`{name}`](#{name.lower()})"
    kind = schema.get("type", "any")
    if kind == "array" and isinstance(schema.get("items"), dict):
        return f"array of {_type(schema['items'])}"
    if "anyOf" in schema or "oneOf" in schema:
        return " or ".join(_type(s) for s in schema.get("anyOf", schema.get("oneOf", [])))
    return " or ".join(kind) if isinstance(kind, list) else str(kind)


def _properties(schema: dict, heading: str, lines: list[str]) -> None:
    properties = schema.get("properties", {})
    if not properties:
        return
    required = set(schema.get("required", ()))
    lines += ["", heading, "", "| property | type | required | meaning |", "|---|---|---|---|"]
    for name, sub in properties.items():
        lines.append(f"| `{name}` | {cell(_type(sub))} | {'yes' if name in required else ''} | "
                     f"{cell(sub.get('description', ''))} |")


def schema_page(path: Path) -> str:
    """The page of one schema file."""
    schema = json.loads(path.read_text(encoding="utf-8"))
    lines = [HEADER + f"# {schema['title']}", "", cell(schema.get("description", "")), "",
             f"JSON Schema (draft 2020-12): [`{path.name}`]({path.name})."]
    _properties(schema, "## Properties", lines)
    for name, sub in schema.get("$defs", {}).items():
        if sub.get("properties"):
            text = cell(sub.get("description", ""))
            _properties(sub, f"## `{name}`" + (f"\n\n{text}" if text else ""), lines)
    return "\n".join(lines) + "\n"


def schema_pages(folder: Path = SCHEMA_DIR) -> dict[str, Callable[[], str]]:
    """Repository-relative page path -> its renderer, for each NAME.schema.json in `folder`."""
    return {(folder / path.name.replace(".schema.json", ".md")).relative_to(REPO).as_posix():
            functools.partial(schema_page, path) for path in sorted(folder.glob("*.schema.json"))}


__all__ = ["SCHEMA_DIR", "schema_page", "schema_pages"]
