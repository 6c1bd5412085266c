"""The code blocks of README.md and docs/ and the ``<!-- doc-test: KIND -->`` comment above each: one scanner
for the doc tests (test_doc_blocks.py: every block; test_doc_examples.py: the companion blocks;
test_doc_examples_python.py: the Python blocks run as scripts)."""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
MARKER = re.compile(r"<!--\s*doc-test:\s*(?P<spec>[^>]*?)\s*-->")


@dataclass
class Block:
    where: str          # docs/x.md:LINE of the block's first line
    kind: str | None    # the marker's text (``companion uav1``, ``python ends "REGEX"``, ``shell``), None: unmarked
    lang: str
    lines: list[str]


def _marker(lines: list[str], i: int) -> str | None:
    """The doc-test spec on the line above line i (a blank line may sit between, as Markdown wants)."""
    for j in (i - 1, i - 2):
        if j >= 0 and (m := MARKER.search(lines[j])):
            return m["spec"]
        if j >= 0 and lines[j].strip():
            return None
    return None


def blocks(doc: Path) -> list[Block]:
    """The fenced blocks, and the indented blocks that stand on their own (not inside a list item)."""
    lines = doc.read_text().splitlines()
    rel = doc.relative_to(ROOT)
    out: list[Block] = []
    i = 0
    while i < len(lines):
        line = lines[i]
        if line.startswith("```"):
            end = next(j for j in range(i + 1, len(lines)) if lines[j].startswith("```"))
            out.append(Block(f"{rel}:{i + 1}", _marker(lines, i), line[3:].strip(), lines[i + 1:end]))
            i = end + 1
            continue
        before = next((lines[j] for j in range(i - 1, -1, -1) if lines[j].strip()), "")
        if (line.startswith("    ") and line.strip() and i > 0 and not lines[i - 1].strip()
                and not before.startswith((" ", "-", "*", "|")) and not re.match(r"\d+\.", before)):
            end = i
            while end < len(lines) and (lines[end].startswith("    ") or not lines[end].strip()):
                end += 1
            body = [x[4:] for x in lines[i:end]]
            while body and not body[-1].strip():
                body.pop()
            out.append(Block(f"{rel}:{i + 1}", _marker(lines, i), "", body))
            i = end
            continue
        i += 1
    return out


def all_blocks() -> list[Block]:
    return [b for doc in DOCS for b in blocks(doc)]
