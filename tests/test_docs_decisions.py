"""The project cites its own docs, by sections that exist (issue 12).

The fixed decisions the code follows are written down in docs/ICD.md (the wire) and
docs/CONFIG.md (the config file). Code and docs cite them by doc and section, as
`docs/ICD.md, "Axis scaling"` (inside docs/ also `ICD.md, "Axis scaling"`, or a link
`ICD.md#axis-scaling`), never by a file outside the repository. This test fails when a file
in usb2rc/, tests/, docs/, bench/ or README.md names the shared specs' decisions file or a
path into the shared folder, when a citation names a doc the repository does not have, or a
section that is not a heading of that doc.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCANNED = ["usb2rc", "tests", "docs", "bench", "README.md"]
SKIPPED_DIRS = {"__pycache__", ".pytest_cache", ".hypothesis"}

# Written so that this file does not match itself.
OUTSIDE = re.compile(r"DECISIONS\.md|(?:\.\./|/work/)shared\b", re.IGNORECASE)

# `docs/ICD.md, "Failsafe" and "Sequences"`, `ICD.md, "Failsafe", "Sequences"`; a citation
# may wrap onto the next line (whitespace, and a comment's `#`, between its parts).
_GAP = r"(?:\s|#)*"
CITATION = re.compile(
    rf'\b((?:docs/|bench/)?[A-Za-z][\w-]*\.md),{_GAP}("[^"\n]+"(?:{_GAP}(?:,|and|or){_GAP}"[^"\n]+")*)'
)
QUOTED = re.compile(r'"([^"\n]+)"')
# `[text](ICD.md#axis-scaling)`, `(docs/ICD.md#failsafe)`
ANCHOR_LINK = re.compile(r"\]\(((?:[\w./-]+/)?[\w-]+\.md)#([\w-]+)\)")
SEE = re.compile(r'\bsee "([^"\n]+)"')
HEADING = re.compile(r"^#{1,6}\s+(.+?)\s*#*\s*$")
FENCE = re.compile(r"^\s*(```|~~~)")


def scanned_files() -> list[Path]:
    files: list[Path] = []
    for name in SCANNED:
        path = ROOT / name
        if path.is_file():
            files.append(path)
            continue
        for f in sorted(path.rglob("*")):
            if f.is_file() and not SKIPPED_DIRS.intersection(f.relative_to(ROOT).parts):
                files.append(f)
    return files


def text_of(path: Path) -> str | None:
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        return None  # binary data (captures, recordings in binary form)


TEXTS = {f: t for f in scanned_files() if (t := text_of(f)) is not None}


def headings(doc: Path) -> list[str]:
    found, inside = [], False
    for line in doc.read_text(encoding="utf-8").splitlines():
        if FENCE.match(line):
            inside = not inside
        elif not inside and (m := HEADING.match(line)):
            found.append(m.group(1))
    return found


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[`*_]", "", heading).strip().lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def resolve(name: str, citing: Path) -> Path | None:
    """The doc a citation names: a path from the repository root (`docs/ICD.md`), or a name
    relative to the citing file's folder, or a file in docs/ (`ICD.md` in a comment)."""
    for base in (ROOT, citing.parent, ROOT / "docs"):
        if (base / name).is_file():
            return base / name
    return None


def line_of(text: str, pos: int) -> int:
    return text.count("\n", 0, pos) + 1


def citations() -> list[tuple[Path, int, str, str]]:
    """(citing file, line, doc name, section) for every citation of a doc's section."""
    found = []
    for path, text in TEXTS.items():
        for m in CITATION.finditer(text):
            for section in QUOTED.findall(m.group(2)):
                found.append((path, line_of(text, m.start()), m.group(1), section))
    return found


def anchor_links() -> list[tuple[Path, int, str, str]]:
    found = []
    for path, text in TEXTS.items():
        if path.suffix == ".md":
            for m in ANCHOR_LINK.finditer(text):
                found.append((path, line_of(text, m.start()), m.group(1), m.group(2)))
    return found


def where(path: Path, line: int) -> str:
    return f"{path.relative_to(ROOT)}:{line}"


def test_nothing_cites_files_outside_the_repository() -> None:
    bad = [
        f"{where(path, number)}: {line.strip()}"
        for path, text in TEXTS.items()
        for number, line in enumerate(text.splitlines(), 1)
        if OUTSIDE.search(line)
    ]
    assert not bad, "cite docs/ICD.md or docs/CONFIG.md instead:\n" + "\n".join(bad)


def test_every_cited_section_is_a_heading_of_the_cited_doc() -> None:
    bad = []
    for path, number, name, section in citations():
        doc = resolve(name, path)
        if doc is None:
            bad.append(f"{where(path, number)}: {name} is not in the repository")
        elif section not in headings(doc):
            bad.append(f'{where(path, number)}: {name} has no heading "{section}"')
    assert not bad, "\n".join(bad)


def test_every_anchor_link_has_its_heading() -> None:
    bad = []
    for path, number, name, anchor in anchor_links():
        doc = (path.parent / name).resolve()
        if not doc.is_file():
            bad.append(f"{where(path, number)}: {name} does not exist")
        elif anchor not in {slug(h) for h in headings(doc)}:
            bad.append(f"{where(path, number)}: {name} has no heading with anchor #{anchor}")
    assert not bad, "\n".join(bad)


def test_the_docs_see_their_own_headings() -> None:
    """`see "Section"` inside a doc points at a heading of that doc."""
    bad = []
    for doc in sorted((ROOT / "docs").glob("*.md")):
        text, own = TEXTS[doc], set(headings(doc))
        for m in SEE.finditer(text):
            if m.group(1) not in own:
                bad.append(f'{where(doc, line_of(text, m.start()))}: no heading "{m.group(1)}"')
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize(
    ("citing", "section"),
    [
        ("usb2rc/nodes/mapping.py", "Axis scaling"),
        ("usb2rc/nodes/mapping.py", "Default axis layout"),
        ("usb2rc/nodes/mapping.py", "Failsafe"),
        ("usb2rc/nodes/node_ids.py", "Node-IDs"),
        ("tests/daemon_harness.py", "Default button layout"),
    ],
)
def test_the_citations_are_found(citing: str, section: str) -> None:
    """The regex sees the citations the code makes (so the test above checks something)."""
    sections = {s for path, _, name, s in citations() if path == ROOT / citing}
    assert section in sections


@pytest.mark.parametrize(
    "section",
    [
        # one heading per fixed decision; the code and tests cite them by these names
        "C2-16B data frame",
        "Byte order",
        "Data statuses",
        "Message code",
        "Line feed",
        "Axis scaling",
        "Default button layout",
        "Default axis layout",
        "Service frames",
        "Service status byte",
        "Device string",
        "Device error codes",
        "Sequences",
        "Node-IDs",
        "Failsafe",
        "Timing and bandwidth",
        "The serial line lost and back",
        "A stalled line",
        "SUMD (HoTT) output",
        "UART receive",
    ],
)
def test_the_icd_holds_each_decision(section: str) -> None:
    assert section in headings(ROOT / "docs" / "ICD.md")


def test_slug_matches_github() -> None:
    assert slug("SUMD (HoTT) output") == "sumd-hott-output"
    assert slug("C2-16B data frame") == "c2-16b-data-frame"
    assert slug("Node-IDs") == "node-ids"
