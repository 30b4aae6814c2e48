"""Which path the hot path's modules take: compiled by mypyc at install, or interpreted.

setup.py compiles the modules a tick and a report run through (its HOT_MODULES) with mypyc
where it can. A compiled module is an extension beside its source, and Python imports an
extension first. The source must run instead in four cases, and `choose()` (called by
`usb2rc/__init__.py`, before any of them is imported) then makes the import system load
every one of them from its source, all at once: compiled modules call each other directly,
so a mix would run old code beside new.
- The source changed since the build (an editable install being worked on): the hashes
  setup.py wrote (`_compiled_sources.txt`) no longer match.
- The compiled modules' shared library is missing (its build failed), or the sources file
  is (a build that stopped half-way): every extension beside a source is then passed over.
- USB2RC_NO_MYPYC is set (the hot path's source, the C loops still on: CI's second pass),
  or USB2RC_PURE_PYTHON (every compiled part off, the C loops too: a suspected fault in a
  compiled part ruled out in the field).
`status()` says which path runs, and why, for the daemon's log at start.
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import importlib.util
import os
import sys
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from importlib.machinery import ModuleSpec
from pathlib import Path
from types import ModuleType

PURE_PYTHON_ENV = "USB2RC_PURE_PYTHON"  # the same switch as the C loops' (hid.speedups)
NO_MYPYC_ENV = "USB2RC_NO_MYPYC"  # this path's own switch
SOURCES_FILE = "_compiled_sources.txt"
PACKAGE_DIR = Path(__file__).resolve().parent


class SourceFirst(importlib.abc.MetaPathFinder):
    """Finds each of `sources` (module name → its .py file) from its source, before the
    path's finder would find its compiled extension."""

    def __init__(self, sources: dict[str, Path]) -> None:
        self.sources = sources

    def find_spec(
        self,
        fullname: str,
        path: Sequence[str] | None,
        target: ModuleType | None = None,
    ) -> ModuleSpec | None:
        source = self.sources.get(fullname)
        if source is None:
            return None
        return importlib.util.spec_from_file_location(fullname, source)


def digest(source: Path) -> str:
    """A source's CRC-32, as setup.py wrote it: a change is what it looks for, not a forgery
    (zlib is loaded anyway; hashlib would load OpenSSL, ~3 MB of the daemon's memory)."""
    return f"{zlib.crc32(source.read_bytes()):08x}"


def _source(module: str) -> Path:
    return PACKAGE_DIR.parent.joinpath(*module.split(".")).with_suffix(".py")


def _compiled(module: str) -> bool:
    """Whether an extension of `module` sits beside its source."""
    source = _source(module)
    return any(
        source.with_suffix(suffix).exists() for suffix in importlib.machinery.EXTENSION_SUFFIXES
    )


def extensions_without_sources_file() -> list[str]:
    """The modules of the package with an extension beside their source (the package's
    extensions looked at, not each of its sources)."""
    modules = {
        ".".join(extension.relative_to(PACKAGE_DIR.parent).parts[:-1])
        + "."
        + extension.name.split(".", 1)[0]
        for suffix in importlib.machinery.EXTENSION_SUFFIXES
        for extension in PACKAGE_DIR.rglob(f"*{suffix}")
    }
    return sorted(module for module in modules if _source(module).exists())


def read_sources(text: str) -> tuple[str, dict[str, str]]:
    """The shared library's name and each compiled module's source hash, from the file
    setup.py wrote."""
    group, hashes = "", {}
    for line in text.splitlines():
        key, _, value = line.partition(" ")
        if key == "group":
            group = value
        elif key:
            hashes[key] = value
    return group, hashes


def why_interpreted(hashes: dict[str, str], group_built: bool, switched_off: str) -> str | None:
    """Why the compiled modules must not run (None: they may); `switched_off`: the variable
    that switched them off ("": none)."""
    if switched_off:
        return f"switched off ({switched_off})"
    if not group_built:
        return "their shared library was not built"
    changed = [module for module, known in hashes.items() if digest(_source(module)) != known]
    if changed:
        return (
            f"{len(changed)} changed since the build ({', '.join(sorted(changed)[:3])}"
            f"{', ...' if len(changed) > 3 else ''}): `pip install -e .` compiles them again"
        )
    return None


@dataclass
class Choice:
    """What `choose()` found, for `status()`."""

    compiled: list[str] = field(default_factory=list)  # modules whose extension was built here
    reason: str | None = None  # why they run interpreted (None: they run compiled)


CHOICE = Choice()


def choose() -> None:
    """Once, before any hot-path module is imported: load them from their source when the
    compiled ones must not run (see the module docstring)."""
    sources_file = PACKAGE_DIR / SOURCES_FILE
    if not sources_file.exists():
        # built without mypyc, or a source checkout; or a build that stopped between writing
        # the extensions and the file: any extension with a source beside it then loads
        # from its source (the C loops have none)
        CHOICE.compiled = extensions_without_sources_file()
        if CHOICE.compiled:
            CHOICE.reason = f"have no {SOURCES_FILE} (an interrupted build?): reinstall usb2rc"
            sys.meta_path.insert(0, SourceFirst({m: _source(m) for m in CHOICE.compiled}))
        return
    group, hashes = read_sources(sources_file.read_text())
    CHOICE.compiled = [module for module in hashes if _compiled(module)]
    if not CHOICE.compiled:
        return
    switched_off = next(
        (name for name in (NO_MYPYC_ENV, PURE_PYTHON_ENV) if os.environ.get(name, "0") != "0"),
        "",
    )
    group_built = importlib.util.find_spec(f"{group}__mypyc") is not None
    CHOICE.reason = why_interpreted(hashes, group_built, switched_off)
    if CHOICE.reason is not None:
        sys.meta_path.insert(0, SourceFirst({module: _source(module) for module in hashes}))


def compiled_active() -> bool:
    """Whether the hot path's modules run compiled in this process."""
    return bool(CHOICE.compiled) and CHOICE.reason is None


def status() -> str:
    """One line: which path the hot path's modules take, and why."""
    if not CHOICE.compiled:
        return (
            "hot path interpreted: its modules were not compiled here (mypyc needs gcc and "
            "Python's headers at install: `sudo apt install gcc python3-dev`, then reinstall)"
        )
    if CHOICE.reason is not None:
        return f"hot path interpreted: its {len(CHOICE.compiled)} compiled modules {CHOICE.reason}"
    return f"hot path compiled: {len(CHOICE.compiled)} modules (mypyc)"
