"""The shell commands the documentation shows, collected from its pages (README.md and docs/**/*.md).

A command is a line of a fenced ``bash``/``sh``/``shell``/``console`` block (a ``\\`` at the end of a
line continues it; ``#`` starts a comment), or a line beginning with ``$ `` in a block of another
kind (an example with its output). A page says a command is not run by the test, and why, with an
HTML comment on the lines right above the block (it shows nowhere)::

    <!-- not-run: the reason (real hardware, ...) -->                      every command of the block
    <!-- not-run "--port /dev/ttyUSB0": a GRBL board on a USB port -->     the commands containing the quoted text

tests/docs/test_page_commands.py runs the rest (see there for what it puts in place of DATASET, ``~``,
``/tmp/...`` and the other names the pages use) and parses the ``lfstudio`` commands it does not run.
"""

from __future__ import annotations

import re
import shlex
from dataclasses import dataclass, field
from pathlib import Path

#: fence languages whose every line is a command
SHELL_LANGUAGES = {"bash", "sh", "shell", "console", "shell-session"}
_FENCE = re.compile(r"^(\s*)(`{3,}|~{3,})\s*([^\s`]*)")
_NOT_RUN = re.compile(r"<!--\s*not-run(?:\s+\"([^\"]+)\")?\s*:\s*(.*?)\s*-->")


@dataclass
class Command:
    page: str               # path from the repository's root
    line: int               # the page's line where the command begins (1-based)
    text: str               # as the page shows it (continuations joined, comment removed)
    not_run: str = ""       # the page's reason for not running it ("" runs it)
    output: list[str] = field(default_factory=list)     # what a ``$ `` example shows it print (its lines)

    @property
    def where(self) -> str:
        return f"{self.page}:{self.line}"

    def words(self) -> list[str]:
        return shlex.split(self.text, comments=True)


@dataclass
class Block:
    page: str
    line: int               # the fence's line
    language: str
    commands: list[Command] = field(default_factory=list)

    @property
    def where(self) -> str:
        return f"{self.page}:{self.line}"


def pages(root: Path) -> list[Path]:
    docs = sorted(p for p in (root / "docs").rglob("*.md") if "_build" not in p.relative_to(root / "docs").parts)
    return [root / "README.md", *docs]


def blocks_of(path: Path, root: Path) -> list[Block]:
    """The blocks of one page that show at least one command."""
    rel = path.relative_to(root).as_posix()
    lines = path.read_text(encoding="utf-8").splitlines()
    found: list[Block] = []
    i = 0
    while i < len(lines):
        m = _FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        fence, language = m.group(2), m.group(3).lower()
        markers = []
        j = i - 1
        while j >= 0 and (lines[j].strip().startswith("<!--") and "not-run" in lines[j]):
            markers += _NOT_RUN.findall(lines[j])
            j -= 1
        end = i + 1
        while end < len(lines) and not lines[end].strip().startswith(fence[0] * len(fence)):
            end += 1
        block = Block(rel, i + 1, language)
        if not language.startswith("{"):              # MyST directives ({toctree}, {eval-rst}, ...) show none
            _collect(block, lines, i + 1, end, markers)
        if block.commands:
            found.append(block)
        i = end + 1
    return found


def _collect(block: Block, lines: list[str], start: int, end: int, markers: list[tuple[str, str]]) -> None:
    shell = block.language in SHELL_LANGUAGES
    k = start
    while k < end:
        first = k
        text = lines[k].strip()
        if not shell:
            if not text.startswith("$ "):
                k += 1
                continue
            text = text[2:]
        elif text.startswith("$ "):
            text = text[2:]
        while text.endswith("\\") and k + 1 < end:
            k += 1
            text = text[:-1].rstrip() + " " + lines[k].strip()
        k += 1
        if not text or text.startswith("#"):
            continue
        words = shlex.split(text, comments=True)
        if not words:
            continue
        shown = shlex.join(words)
        reason = ""
        for quoted, why in markers:
            if not quoted or quoted in text:
                reason = why or "(no reason given)"
        output: list[str] = []
        if not shell:                                 # an example: the lines up to the next prompt are its output
            while k < end and not lines[k].strip().startswith("$ "):
                output.append(lines[k])
                k += 1
        block.commands.append(Command(block.page, first + 1, shown, reason, [ln for ln in output if ln.strip()]))


def all_blocks(root: Path) -> list[Block]:
    return [b for p in pages(root) for b in blocks_of(p, root)]
