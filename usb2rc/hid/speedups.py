"""The HID stage's optional C loops: `usb2rc/hid/_speedups.c`, built at install by setup.py
where a C compiler and Python's headers are (a bare Pi may have neither).

`compiled()` is the built module, or None: not built, or switched off by PURE_PYTHON_ENV.
Each user keeps its Python twin and takes it on None; tests/test_speedups.py holds each C
function to its twin, tests/test_compiled_pull.py the compiled pull of a replay device
(`_speedups.pull`) to the reader's Python pull.
"""

from __future__ import annotations

import os
from types import ModuleType

# Set (to anything but "" or "0"): the Python twins run, as on a machine without the C loops
# (tests compare the two; a suspected fault in the C part can be ruled out in the field).
PURE_PYTHON_ENV = "USB2RC_PURE_PYTHON"

try:
    from usb2rc.hid import _speedups as _built
except ImportError:  # pragma: no cover - a machine where it could not be built
    _built = None  # type: ignore[assignment]


# read once, at import: `compiled()` is asked per batch, and an environment lookup costs
# more than some of the loops it chooses
_SWITCHED_OFF = os.environ.get(PURE_PYTHON_ENV, "") not in ("", "0")


def compiled() -> ModuleType | None:
    return None if _SWITCHED_OFF else _built


def built() -> bool:
    """Whether the C loops were built here (whatever PURE_PYTHON_ENV says)."""
    return _built is not None


def status() -> str:
    """One line for the log at start: which path the HID stage's loops take, and why."""
    if _built is None:
        return (
            "HID C loops not built here: the Python path runs (the same output, more CPU); "
            "`sudo apt install gcc python3-dev` and reinstall usb2rc to build them"
        )
    if _SWITCHED_OFF:
        return f"HID C loops built but switched off ({PURE_PYTHON_ENV}): the Python path runs"
    return "HID C loops: compiled"
