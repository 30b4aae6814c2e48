"""The optional compiled parts, built at install where they can be; everything else is in
pyproject.toml.

- `usb2rc.hid._speedups` (a batch of HID reports drained in one C loop) and
  `usb2rc.nodes._steady` (a steady node's step): C, with a Python twin each.
- The hot path's own modules (HOT_MODULES: what a tick and a report run through), compiled
  from their Python source by mypyc (mypy's compiler, a build requirement): the same code,
  without the interpreter's work per line. The source stays beside each, and runs wherever
  the compiled one cannot (usb2rc.compiled_path).

Every part is optional: where one cannot be built (no C compiler or no Python headers, as on
a bare Pi, or mypyc refuses the modules) the install goes on without it and usb2rc runs the
Python path, which gives the same bytes (tests/test_speedups.py, tests/test_compiled_path.py).
USB2RC_NO_MYPYC (or USB2RC_PURE_PYTHON) set at install builds none of the mypyc modules.
"""

from __future__ import annotations

import os
import sys
import zlib
from glob import glob
from importlib.machinery import EXTENSION_SUFFIXES
from pathlib import Path

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

# The modules of the hot path: the readers' pull, the node step, the line driver and
# sessions, each protocol's own modules (found by their place: a protocol added later is
# compiled without a line here). A class of these cannot be subclassed by an interpreted
# one, so these are not here: runtime/worker.py (every thread subclasses it) and
# hid/replay.py (the benches' backends subclass it; its hot part is C already).
HOT_MODULES = [
    "usb2rc/hid/reader.py",
    "usb2rc/nodes/binding.py",
    "usb2rc/nodes/guard.py",
    "usb2rc/nodes/presses.py",
    "usb2rc/nodes/scaling.py",
    "usb2rc/nodes/silence.py",
    "usb2rc/nodes/steady.py",
    "usb2rc/nodes/step.py",
    "usb2rc/nodes/switches.py",
    "usb2rc/nodes/table.py",
    "usb2rc/nodes/trims.py",
    "usb2rc/lines/driver.py",
    "usb2rc/lines/link.py",
    "usb2rc/lines/rx.py",
    "usb2rc/lines/serial_link.py",
    "usb2rc/lines/session.py",
    "usb2rc/lines/udp_link.py",
    "usb2rc/runtime/flag.py",
    "usb2rc/runtime/load.py",
    "usb2rc/runtime/samples.py",
    # every module of every protocol's package but its output (its builder and registry
    # row, run once at start)
    *sorted(
        path
        for path in glob("usb2rc/protocols/*/*.py")
        if Path(path).name not in ("__init__.py", "output.py")
    ),
    # after the protocols that import them: given first, mypy 2.4's build could not
    # determine `rc11.BLOCK_LEN` in sbus/codec.py (an import cycle through the package)
    "usb2rc/protocols/channels.py",
    "usb2rc/protocols/crc.py",
    "usb2rc/protocols/rc11.py",
    "usb2rc/protocols/rc11_channels.py",
]
# the compiled modules' shared library (a top-level module beside the package)
GROUP = "usb2rc_hot"
# what the compiled modules were built from, written beside them (in the build, or in the
# tree for an in-place build): usb2rc.compiled_path runs the source instead when a
# module's source no longer matches (an editable install being worked on)
SOURCES_FILE = "usb2rc/_compiled_sources.txt"

C_PARTS = [
    Extension("usb2rc.hid._speedups", ["usb2rc/hid/_speedups.c"], optional=True),
    Extension("usb2rc.nodes._steady", ["usb2rc/nodes/_steady.c"], optional=True),
]


def digest(source: Path) -> str:
    """A source's CRC-32 (usb2rc.compiled_path.digest: a change, not a forgery, is what it
    looks for; zlib is loaded anyway, hashlib would load OpenSSL, ~3 MB)."""
    return f"{zlib.crc32(source.read_bytes()):08x}"


def _module_name(path: str) -> str:
    return path.removesuffix(".py").replace("/", ".")


def _remove_old_extensions(root: Path, compiled: list[str]) -> None:
    """An in-place build (an editable install) leaves the extension of a module compiled
    before beside its source: one no longer in `compiled` would be imported first, and fail."""
    for source in (root / "usb2rc").rglob("*.py"):
        if source.relative_to(root).as_posix() in compiled:
            continue
        for suffix in EXTENSION_SUFFIXES:
            source.with_suffix(suffix).unlink(missing_ok=True)


def compiled_modules() -> tuple[list[Extension], str]:
    """The mypyc extensions of HOT_MODULES, each optional, and the sources file's text (what
    they are built from); none where mypyc is missing or refuses them (the build says why,
    and goes on)."""
    if any(os.environ.get(name, "0") != "0" for name in ("USB2RC_NO_MYPYC", "USB2RC_PURE_PYTHON")):
        return [], ""
    sources = "\n".join(
        [f"group {GROUP}", *(f"{_module_name(p)} {digest(Path(p))}" for p in HOT_MODULES)]
    )
    try:
        from mypyc.build import mypycify

        # the build environment has none of usb2rc's dependencies: their types are Any here
        extensions: list[Extension] = mypycify(
            ["--ignore-missing-imports", *HOT_MODULES],
            opt_level="3",
            multi_file=True,
            group_name=GROUP,
        )
    except (Exception, SystemExit) as exc:  # mypy's errors end in SystemExit
        print(f"usb2rc: the hot path stays interpreted (mypyc: {exc!r})", file=sys.stderr)
        return [], ""
    for extension in extensions:
        extension.optional = True
    return extensions, sources + "\n"


COMPILED, SOURCES = compiled_modules()


class BuildExt(build_ext):
    """build_ext, then the sources file beside what it built, where it built it: the tree
    (in place: an editable install) or the build's directory (a wheel), never both. There it
    also removes the extensions of modules no longer compiled, and the sources file of a
    build that compiled none."""

    def run(self) -> None:
        super().run()
        # where the build puts the package: the tree, or the build's own directory (which
        # an earlier build may have left extensions in, as the tree does)
        root = Path.cwd() if self.inplace else Path(self.build_lib)
        _remove_old_extensions(root, HOT_MODULES if SOURCES else [])
        (root / SOURCES_FILE).unlink(missing_ok=True)
        if SOURCES:
            (root / SOURCES_FILE).write_text(SOURCES)


setup(ext_modules=[*C_PARTS, *COMPILED], cmdclass={"build_ext": BuildExt})
