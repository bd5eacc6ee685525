"""The documentation stays true: every code block in docs/ is checked, every internal link resolves, and every
citation of a documentation page in the code points at a page and heading that exist.

Code blocks, by language:
- `python`: the blocks of a page run in order in one folder, in one process;
- `toml`: loaded through the configuration loader, merged over `bench.example.toml` (or over
  `thermal.example.toml` when the block configures the chamber), as a bench configuration with that section;
- `sh`: every `bench ...` command is parsed by the real argument parser; then the blocks run, in order, in one
  folder per page, with `bench` the worktree's `python -m bench.cli`. The folder holds `runs/ID.mcap` and
  `runs/ID.result.json` (a recorded short simulated run) and the example configurations. `pip install` commands
  are not run (the package is installed).

A marker on the line before a block changes what is done with it (`<!-- docs-check: MARKER -->`):
- `hardware`: needs what a test cannot give (a real device, a second terminal, an interactive terminal, a lab's
  cluster, files of your own): commands are parsed, not run; a TOML block is parsed, not loaded;
- `slow`: runs only in the slow test (`pytest -m slow`);
- `expect-error`: a TOML block the loader must refuse with one line;
- `register-map`: a TOML block that is a turntable's Modbus register map file (`[modbus]`);
- `schedule`: a TOML block that shows a schedule file's keys (both step tables at once, so no one file): every key
  must be one the schedule loader knows, at the top and in each `[[position]]` and `[[rotation]]`.
"""

from __future__ import annotations

import re
import shlex
import shutil
import tomllib
import unicodedata
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.helpers.docs_shell import THERMAL_RUN_COMMAND, run_bench_shell, same_command, with_examples

REPO = Path(__file__).resolve().parents[2]
DOCS = REPO / "docs"
PAGES = sorted(DOCS.rglob("*.md"))
MARKERS = {"hardware", "slow", "expect-error", "register-map", "schedule"}

_BLOCK = re.compile(r"(?:^[ \t]*<!-- docs-check: ([\w-]+) -->\n)?^([ \t]*)```(\w+)[^\n]*\n(.*?)^\2```", re.S | re.M)


@dataclass(frozen=True)
class Block:
    page: Path
    line: int
    lang: str
    marker: str | None
    text: str

    def where(self) -> str:
        return f"{self.page.relative_to(REPO)}:{self.line}"


def blocks(page: Path, lang: str | None = None) -> list[Block]:
    text = page.read_text(encoding="utf-8")
    found = []
    for m in _BLOCK.finditer(text):
        indent = m.group(2)
        body = "".join(line[len(indent):] if line.startswith(indent) else line
                       for line in m.group(4).splitlines(keepends=True))
        block = Block(page, text.count("\n", 0, m.start(3)) + 1, m.group(3), m.group(1), body)
        if lang is None or block.lang == lang or (lang == "sh" and block.lang == "bash"):
            found.append(block)
    return found


def all_blocks(lang: str) -> list[Block]:
    return [b for page in PAGES for b in blocks(page, lang)]


def test_every_marker_is_one_the_checks_understand():
    for page in PAGES:
        for block in blocks(page):
            assert block.marker in MARKERS | {None}, f"{block.where()}: unknown marker {block.marker!r}"
        for m in re.finditer(r"<!-- docs-check: ([\w-]+) -->\n(?![ \t]*```)", page.read_text(encoding="utf-8")):
            raise AssertionError(f"{page.relative_to(REPO)}: marker {m.group(1)!r} not right above a code block")


# --- shell blocks --------------------------------------------------------------------------------------------------

def commands(block: Block) -> list[list[str]]:
    """The `bench` commands of a shell block, as argument lists (comments and `pip install` left out)."""
    found = []
    for line in block.text.splitlines():
        words = shlex.split(line, comments=True)
        command: list[str] = []
        for word in [*words, "&&"]:
            if word in ("&&", ";", "|"):
                if command and command[0] == "bench":
                    found.append(command[1:])
                command = []
            else:
                command.append(word)
    return found


def test_every_bench_command_in_the_docs_parses():
    from bench.cli.main import build_parser

    parser = build_parser(load_all=True)
    checked = 0
    for block in all_blocks("sh"):
        for args in commands(block):
            try:
                parser.parse_args(args)
            except SystemExit as exc:
                raise AssertionError(f"{block.where()}: `bench {shlex.join(args)}` does not parse") from exc
            checked += 1
    assert checked > 30


@pytest.fixture
def recorded_run(short_run) -> dict[str, Path]:
    return {"ID.mcap": short_run.log, "ID.result.json": short_run.result}


def page_folder(tmp_path: Path, recorded: dict[str, Path]) -> Path:
    runs = tmp_path / "runs"
    runs.mkdir()
    for name, source in recorded.items():
        shutil.copyfile(source, runs / name)
    return with_examples(tmp_path)


def run_shell(block: Block, folder: Path, request: pytest.FixtureRequest) -> None:
    """Runs the block's commands in `folder`; a command that the session recorded already, run the same way in a
    folder like this one (`documented_thermal_run`), is not run again: its outputs are copied to where it writes
    them, and the block's other commands read them there."""
    lines = block.text.splitlines()
    for index, line in enumerate(lines):
        if line.strip() and same_command(line, THERMAL_RUN_COMMAND):
            recorded = request.getfixturevalue("documented_thermal_run")
            shutil.copytree(recorded.out, folder / "runs" / "thermal-run")
            lines[index] = ""
    done = run_bench_shell("\n".join(lines), folder)
    assert done.returncode == 0, \
        f"{block.where()}: exit {done.returncode}\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}"


def shell_pages(slow: bool) -> list[Path]:
    return [p for p in PAGES if any((b.marker == "slow") == slow and b.marker != "hardware" for b in blocks(p, "sh"))]


@pytest.mark.slow        # each page's commands run bench on a recorded run: seconds a page (the quick loop parses them)
@pytest.mark.parametrize("page", shell_pages(slow=False), ids=lambda p: str(p.relative_to(DOCS)))
def test_shell_blocks_run_on_the_simulator(page, tmp_path, recorded_run, request):
    folder = page_folder(tmp_path, recorded_run)
    for block in blocks(page, "sh"):
        if block.marker is None:
            run_shell(block, folder, request)


@pytest.mark.slow
@pytest.mark.timeout(900)      # whole simulated runs: minutes under load
@pytest.mark.parametrize("page", [
    # the page that shows the thermal run reads the session's recording: on the worker that makes it (tests/conftest.py)
    pytest.param(page, marks=pytest.mark.xdist_group("documented_thermal_run"))
    if THERMAL_RUN_COMMAND in page.read_text(encoding="utf-8") else page
    for page in shell_pages(slow=True)], ids=lambda p: str(p.relative_to(DOCS)))
def test_slow_shell_blocks_run_on_the_simulator(page, tmp_path, recorded_run, request):
    folder = page_folder(tmp_path, recorded_run)
    for block in blocks(page, "sh"):
        if block.marker in (None, "slow"):
            run_shell(block, folder, request)


# --- TOML blocks ---------------------------------------------------------------------------------------------------

def merged(base: dict, over: dict, depth: int = 0) -> dict:
    """`base` with the sections of `over`: a top-level section's keys go over the base's, a table below it
    (`[imu.signals]`, `[chamber.modbus]`) replaces the base's whole."""
    out = dict(base)
    for key, value in over.items():
        nested = depth == 0 and isinstance(value, dict) and isinstance(out.get(key), dict)
        out[key] = merged(out[key], value, depth + 1) if nested else value
    return out


def toml_text(doc: dict, prefix: tuple[str, ...] = ()) -> str:
    """A TOML document of `doc` (tables, strings, numbers, booleans, arrays, inline tables)."""
    def value(v) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(v, (int, float)):
            return repr(v)
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        if isinstance(v, dict):
            return "{" + ", ".join(f'"{k}" = {value(x)}' for k, x in v.items()) + "}"
        raise TypeError(type(v))
    scalars = [f'"{k}" = {value(v)}' for k, v in doc.items() if not isinstance(v, dict)]
    text = (f"[{'.'.join(prefix)}]\n" if prefix else "") + "".join(line + "\n" for line in scalars)
    for k, v in doc.items():
        if isinstance(v, dict):
            text += toml_text(v, (*prefix, k))
    return text


@pytest.mark.parametrize("block", all_blocks("toml"), ids=lambda b: b.where())
def test_toml_blocks_load_through_the_configuration_loader(block, tmp_path, short_run):
    from bench.config.load import parse_config
    from bench.errors import BenchError
    from drivers.turntable.modbus_map import RegisterMap

    snippet = tomllib.loads(block.text)
    if block.marker == "hardware":
        return                                       # parsed above: it names files of the user's own
    if block.marker == "register-map":
        RegisterMap.from_dict(snippet["modbus"], source=block.where())
        return
    if block.marker == "schedule":
        from schedules import loader

        assert set(snippet) <= set(loader._REQUIRED_TOP + loader._OPTIONAL_TOP), block.where()
        assert all(set(t) <= set(loader._POSITION_KEYS) for t in snippet.get("position", [])), block.where()
        assert all(set(t) <= set(loader._ROTATION_KEYS) | {"rate_dps"} for t in snippet.get("rotation", [])), \
            block.where()
        return
    base_file = "thermal.example.toml" if "chamber" in snippet else "bench.example.toml"
    base = tomllib.loads((REPO / base_file).read_text(encoding="utf-8"))
    if "dbc" in snippet.get("imu", {}):
        del base["sim"]             # the example's simulated IMU is not this one: no simulated world for it
    shutil.copyfile(short_run.result, tmp_path / "previous.result.json")    # the acceptance example's reference
    shutil.copyfile(REPO / "drivers" / "imu" / "sbg_ecan.dbc", tmp_path / "my-sbg.dbc")   # the sbg-ecan example's
    text = toml_text(merged(base, snippet))
    if block.marker == "expect-error":
        with pytest.raises(BenchError) as refused:
            parse_config(text, block.where(), base_dir=tmp_path)
        assert "\n" not in str(refused.value)
        said = re.search(r"# refused: FILE:LINE: ([\w.]+):", block.text)
        assert said, f"{block.where()}: an expect-error block says what is refused (# refused: FILE:LINE: KEY: ...)"
        assert f": {said.group(1)}:" in str(refused.value), \
            f"{block.where()}: refused for another reason: {refused.value}"
        return
    parse_config(text, block.where(), base_dir=tmp_path)


# --- Python blocks -------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("page", [p for p in PAGES if blocks(p, "python")], ids=lambda p: str(p.relative_to(DOCS)))
def test_python_blocks_run(page, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    for block in blocks(page, "python"):
        exec(compile(block.text, block.where(), "exec"), namespace)
    if page.name == "python.md":
        out = capsys.readouterr().out
        assert (tmp_path / "demo.result.json").exists()
        assert "Kg_x" in out
        # the driver example prints each axis's state in words, not status numbers such as '5'
        assert "outer    10.0000 deg  position  enabled, in position" in out, out
        # the chamber example: three hours of simulated chamber time at -20 degC
        assert "-20.0 degC, setpoint -20.0 degC, ramp 2 degC/min, running, alarms: none" in out, out


# --- links and citations -------------------------------------------------------------------------------------------

def slug(heading: str) -> str:
    """The anchor MkDocs (Python-Markdown's toc) gives a heading."""
    # emphasis marks go (an underscore only at a word's edge: `thermal_model` keeps its own)
    text = re.sub(r"[`*]|(?<!\w)_|_(?!\w)|\[([^\]]*)\]\([^)]*\)", lambda m: m.group(1) or "", heading)
    text = unicodedata.normalize("NFKD", text).encode("ascii", "ignore").decode("ascii")
    text = re.sub(r"[^\w\s-]", "", text).strip().lower()
    return re.sub(r"[-\s]+", "-", text)


def anchors(page: Path) -> set[str]:
    text = re.sub(r"^([ \t]*)```.*?^\1```", "", page.read_text(encoding="utf-8"), flags=re.S | re.M)
    return {slug(m.group(1)) for m in re.finditer(r"^#{1,6} (.+?)\s*$", text, re.M)}


def test_every_internal_link_resolves():
    broken = []
    for page in [*PAGES, REPO / "README.md"]:
        text = re.sub(r"^([ \t]*)```.*?^\1```", "", page.read_text(encoding="utf-8"), flags=re.S | re.M)
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z][a-z0-9+.-]*:", target):
                continue                                         # http:, https:, mailto:
            path, _, anchor = target.partition("#")
            file = (page.parent / path).resolve() if path else page
            if not file.exists():
                broken.append(f"{page.relative_to(REPO)}: {target}: no such file")
            elif anchor and file.suffix == ".md" and anchor not in anchors(file):
                broken.append(f"{page.relative_to(REPO)}: {target}: no heading with that anchor")
    assert not broken, "\n".join(broken)


def test_every_page_citation_in_the_code_points_at_a_page_and_heading_that_exist():
    cited = 0
    for folder in ("bench", "drivers", "schedules"):
        for source in sorted((REPO / folder).rglob("*")):
            if source.suffix not in (".py", ".toml", ".dbc", ".md") or not source.is_file():
                continue
            text = source.read_text(encoding="utf-8")
            assert not re.search(r"DESIGN(\.md)? section", text), f"{source}: cites the old DESIGN document"
            for page, anchor in re.findall(r"\b(docs/[\w./-]+\.md)(?:#([\w-]+))?", text):
                assert (REPO / page).is_file(), f"{source.relative_to(REPO)} cites {page}, which does not exist"
                if anchor:
                    assert anchor in anchors(REPO / page), \
                        f"{source.relative_to(REPO)} cites {page}#{anchor}: no such heading"
                cited += 1
    assert cited > 20
