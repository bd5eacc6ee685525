"""The README stays true: its set-up commands come first, CI runs its test command, it stays short and undated,
and every `bench` command it shows parses (its links: tests/architecture/test_docs.py)."""

import re
import shlex
from pathlib import Path

README = Path(__file__).resolve().parents[2] / "README.md"


def test_readme_opens_with_the_two_setup_commands():
    text = README.read_text()
    first_block = re.search(r"```sh\n(.*?)```", text, re.S).group(1).strip().splitlines()
    assert first_block == ["pip install -e . && bench run --sim", "pip install -e '.[test]' && pytest"]
    ci = (README.parent / ".ci" / "run").read_text().strip().splitlines()
    assert ci[-1] == "pip install -e '.[test]' && pytest", "CI's last command is the README's test command"


def test_readme_is_short_and_holds_no_dated_measurement():
    text = README.read_text()
    assert len(text.splitlines()) <= 200
    assert not re.search(r"\b20\d\d-\d\d-\d\d\b|measured|load average", text, re.I), "dated measurements go elsewhere"


def test_every_bench_command_in_the_readme_parses():
    from bench.cli.main import build_parser

    parser = build_parser(load_all=True)
    shown = [shlex.split(line, comments=True) for block in re.findall(r"```sh\n(.*?)```", README.read_text(), re.S)
             for line in block.splitlines()]
    commands = [words[words.index("bench") + 1:] for words in shown if "bench" in words]
    assert len(commands) >= 6
    for args in commands:
        parser.parse_args(args)          # a SystemExit names the bad option on stderr
