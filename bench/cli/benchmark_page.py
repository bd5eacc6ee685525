"""docs/benchmarks.md: the latest figures of each benchmark, from benchmarks/results/NAME.json (written by
benchmarks/results.py's `record` when a benchmark runs)."""

from __future__ import annotations

import json
from pathlib import Path

from bench.cli.reference_pages import HEADER, cell

BENCHMARK_FORMAT = "turntable-bench/benchmark-result"


def _number(value: float) -> str:
    return f"{value:.3g}"


def _one(document: dict) -> list[str]:
    machine = document.get("machine", {})
    load = document.get("load", {})
    lines = ["", f"## {document['benchmark']}", "",
             f"Measured {document['date']} at commit `{document['commit']}` on {machine.get('system', '?')} "
             f"{machine.get('processor', '?')}, {machine.get('cpus', '?')} CPUs, Python {machine.get('python', '?')}; "
             f"load average {load.get('1min', '?')} / {load.get('5min', '?')} / {load.get('15min', '?')} "
             "(1 / 5 / 15 min)."]
    if document.get("parameters"):
        lines += ["", "Parameters: " + ", ".join(f"`{key}` = {value}" for key, value in
                                                  document["parameters"].items()) + "."]
    if document.get("note"):
        lines += ["", cell(document["note"])]
    lines += ["", "| median of | s |", "|---|---|"]
    lines += [f"| {cell(name)} | {_number(value)} |" for name, value in document["medians_s"].items()]
    if document.get("ratios"):
        lines += ["", "| ratio | value |", "|---|---|"]
        lines += [f"| {cell(name)} | {_number(value)} |" for name, value in document["ratios"].items()]
    return lines


def benchmarks_page(folder: Path) -> str:
    """The page from every NAME.json in `folder` (the latest run of each benchmark), by name."""
    lines = [HEADER + "# Benchmarks", "",
             "The latest figures of each benchmark in `benchmarks/`, as it wrote them (`benchmarks/results/`). "
             "Timings depend on the machine and on what else ran on it: each says where and under what load it "
             "was measured. Run one with `python benchmarks/NAME.py` (its docstring says its options), then "
             "`python -m bench.cli.docs_gen` to render this page."]
    documents = []
    for path in sorted(folder.glob("*.json")) if folder.is_dir() else []:
        document = json.loads(path.read_text(encoding="utf-8"))
        if document.get("format") == BENCHMARK_FORMAT:
            documents.append(document)
    if not documents:
        lines += ["", "No benchmark has written its figures yet."]
    for document in sorted(documents, key=lambda d: d["benchmark"]):
        lines += _one(document)
    return "\n".join(lines) + "\n"


__all__ = ["BENCHMARK_FORMAT", "benchmarks_page"]
