"""Regenerate every generated documentation page: `python -m bench.cli.docs_gen` (`--check`: only say which
pages are stale, exit 1 if any).

The pages are rendered from the code (`bench.cli.reference_pages`), the JSON Schemas (`bench.cli.schema_pages`)
and the benchmarks' result files (`bench.cli.benchmark_page`); tests/unit/cli/test_reference_docs.py fails with
this command when a page on disk is not what it renders now.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

from bench.cli.benchmark_page import benchmarks_page
from bench.cli.reference_pages import REGENERATE, REPO, cli_page, configuration_page, exit_codes_page, limits_page
from bench.cli.schema_pages import schema_pages


def pages() -> dict[str, Callable[[], str]]:
    """Repository-relative path -> the function that renders the page."""
    found: dict[str, Callable[[], str]] = {
        "docs/reference/configuration.md": configuration_page,
        "docs/reference/cli.md": cli_page,
        "docs/reference/exit-codes.md": exit_codes_page,
        "docs/reference/limits.md": limits_page,
        "docs/benchmarks.md": lambda: benchmarks_page(REPO / "benchmarks" / "results"),
    }
    found.update(schema_pages())
    return found


def stale(root: Path = REPO) -> list[str]:
    """The generated pages under `root` that differ from what they render now (or are missing)."""
    out = []
    for name, render in pages().items():
        path = root / name
        if not path.is_file() or path.read_text(encoding="utf-8") != render():
            out.append(name)
    return out


def write_all(root: Path = REPO) -> list[str]:
    """Write every page that changed; returns their names."""
    written = []
    for name, render in pages().items():
        path = root / name
        text = render()
        if not path.is_file() or path.read_text(encoding="utf-8") != text:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text, encoding="utf-8")
            written.append(name)
    return written


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=REGENERATE, description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="write nothing; exit 1 when a page is stale")
    parser.add_argument("--root", type=Path, default=REPO, help="the repository the pages go into (default: this "
                        "one)")
    args = parser.parse_args(argv)
    if args.check:
        names = stale(args.root)
        for name in names:
            print(f"stale: {name} (run `{REGENERATE}`)")
        return 1 if names else 0
    for name in write_all(args.root):
        print(f"wrote {name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
