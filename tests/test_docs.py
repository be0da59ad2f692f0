"""The README and docs/ as they are read: their runnable commands run, their command reference
matches the parser, their links resolve, and the results schema names every column.

A fenced ``sh`` block is *runnable* when the line just before its fence is ``<!-- runnable -->``.
Each document's runnable blocks run in order, as written, in one fresh folder per document
(holding a copy of ``budgets.toml``), with this interpreter's ``bin`` first on ``PATH``; every
command must exit 0.  Heavy commands (``make bench``, ``iblbench doctor``, a cluster) are left
unmarked, and the text says so.
"""
from __future__ import annotations

import argparse
import os
import pathlib
import re
import shutil
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
MARKER = "<!-- runnable -->"
FENCE = re.compile(r"^```(\w*)\s*$")
DOCS = [ROOT / "README.md", ROOT / "ARCHITECTURE.md", *sorted((ROOT / "docs").rglob("*.md"))]
BLOCK_SECONDS = 120


def runnable_blocks(text: str) -> list[tuple[int, str]]:
    """(line number of the fence, the block's text) of every block marked runnable.  A marker
    that is not followed by a fenced ``sh`` block is an error, so no block is skipped unseen."""
    lines = text.splitlines()
    blocks = []
    for number, line in enumerate(lines):
        if line.strip() != MARKER:
            continue
        fence = FENCE.match(lines[number + 1]) if number + 1 < len(lines) else None
        if fence is None or fence.group(1) != "sh":
            raise ValueError(f"line {number + 1}: {MARKER} is not followed by a ```sh fence")
        end = next((i for i in range(number + 2, len(lines)) if lines[i].strip() == "```"), None)
        if end is None:
            raise ValueError(f"line {number + 2}: the runnable block is never closed")
        blocks.append((number + 2, "\n".join(lines[number + 2:end])))
    return blocks


def run_block(block: str, folder: pathlib.Path) -> subprocess.CompletedProcess:
    """Run one block as a bash script that stops at the first failing command."""
    env = dict(os.environ, PATH=f"{pathlib.Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")
    return subprocess.run(["bash", "-euo", "pipefail", "-c", block], cwd=folder, env=env,
                          capture_output=True, text=True, timeout=BLOCK_SECONDS)


def test_the_extractor_finds_marked_blocks_only_and_a_broken_command_fails(tmp_path):
    planted = "\n".join([
        "text", "```sh", "iblbench list scenes   # unmarked: not run", "```",
        MARKER, "```sh", "iblbench list estimators >/dev/null", "iblbench no-such-command", "```",
    ])
    blocks = runnable_blocks(planted)
    assert [number for number, _ in blocks] == [6]
    result = run_block(blocks[0][1], tmp_path)
    assert result.returncode == 2 and "no-such-command" in result.stderr
    assert run_block("iblbench list estimators >/dev/null", tmp_path).returncode == 0


def test_a_marker_without_a_shell_block_is_an_error():
    with pytest.raises(ValueError, match="line 2"):
        runnable_blocks("text\n" + MARKER + "\n```python\nprint(1)\n```")


@pytest.mark.parametrize("doc", [d for d in DOCS if MARKER in d.read_text("utf-8")],
                         ids=lambda d: str(d.relative_to(ROOT)))
def test_every_runnable_command_runs_as_written(doc, tmp_path):
    shutil.copy(ROOT / "budgets.toml", tmp_path / "budgets.toml")
    for number, block in runnable_blocks(doc.read_text("utf-8")):
        result = run_block(block, tmp_path)
        assert result.returncode == 0, (f"{doc.relative_to(ROOT)}:{number}: exit {result.returncode}"
                                        f"\n{block}\n{result.stderr[-2000:]}")


def _parser_flags() -> dict[str, set[str]]:
    from iblbench.cli import COMMANDS, build_parser

    subparsers = next(a for a in build_parser()._actions
                      if isinstance(a, argparse._SubParsersAction))
    return {name: {option for action in subparsers.choices[name]._actions
                   for option in action.option_strings if option.startswith("--")} - {"--help"}
            for name in COMMANDS}


def _documented_flags(text: str) -> dict[str, set[str]]:
    """Per ``## `iblbench NAME` `` section of the reference, the flags its table rows name."""
    flags: dict[str, set[str]] = {}
    current = None
    for line in text.splitlines():
        heading = re.match(r"^## `iblbench (\w+)`", line)
        if heading:
            current = flags.setdefault(heading.group(1), set())
        elif line.startswith("## "):
            current = None
        elif current is not None and line.startswith("| `--"):
            current.add(re.match(r"\| `(--[\w-]+)", line).group(1))
    return flags


def test_the_command_reference_names_every_command_and_flag_of_the_parser_and_no_other():
    documented = _documented_flags((ROOT / "docs" / "commands.md").read_text("utf-8"))
    assert documented == _parser_flags()


def test_a_flag_missing_from_the_reference_is_seen():
    text = (ROOT / "docs" / "commands.md").read_text("utf-8").replace("| `--no-flip` |", "| no |")
    assert _documented_flags(text)["run"] == _parser_flags()["run"] - {"--no-flip"}


def test_the_results_schema_names_every_column_and_the_schema_version():
    """Every column is in docs/results.md, but a metric's own columns: a metric documents
    itself (its module's docstring, shown by ``iblbench list metrics``), so that adding one
    touches only its own files."""
    from iblbench.harness.protocol.metric import registered
    from iblbench.harness.protocol.results import COLUMNS, SCHEMA_VERSION

    text = (ROOT / "docs" / "results.md").read_text("utf-8")
    own = {column for m in registered() for column in (m.column, m.renders_column) if column}
    assert [c for c in COLUMNS if f"`{c}`" not in text and c not in own] == []
    assert [m.name for m in registered() if not m.description.strip()] == []
    assert "iblbench list metrics" in text
    assert f"schema version is {SCHEMA_VERSION}" in text


def _anchor(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def test_every_relative_link_and_anchor_resolves():
    broken = []
    for doc in DOCS:
        text = doc.read_text("utf-8")
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+:", target):
                continue
            path, _, anchor = target.partition("#")
            file = (doc.parent / path).resolve() if path else doc
            if not file.exists():
                broken.append(f"{doc.relative_to(ROOT)}: {target}")
            elif anchor and file.suffix == ".md":
                headings = re.findall(r"^#+ (.+)$", file.read_text("utf-8"), re.M)
                if anchor not in {_anchor(h) for h in headings}:
                    broken.append(f"{doc.relative_to(ROOT)}: {target}")
    assert broken == []


def test_the_readme_is_a_manual_not_a_notebook():
    text = (ROOT / "README.md").read_text("utf-8")
    assert len(text.splitlines()) <= 200
    assert re.findall(r"\bissue \d+|\b[0-9a-f]{7,40}\b", text, re.I) == []
