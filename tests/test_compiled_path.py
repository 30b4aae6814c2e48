"""The hot path compiled by mypyc (setup.py's HOT_MODULES) and its source: the same bytes, and
the source whenever the compiled modules must not run (usb2rc.compiled_path).

- Every line session's bytes over a long random journey are the same compiled and
  interpreted (tests/compiled_twin.py, run once each way in its own process).
- USB2RC_NO_MYPYC (or USB2RC_PURE_PYTHON), a source changed since the build, or a missing
  shared library load
  every compiled module from its source; the reason is said.
- Under CI, where the C parts are built, the mypyc modules must be built too: a build that
  fell back to the interpreted path fails here instead of passing slower.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from usb2rc import compiled_path
from usb2rc.hid import speedups

TESTS = Path(__file__).parent


def without_switches() -> dict[str, str]:
    """This process's environment without the switches of the compiled parts."""
    switches = ("USB2RC_NO_MYPYC", "USB2RC_PURE_PYTHON")
    return {key: value for key, value in os.environ.items() if key not in switches}


def twin(env_extra: dict[str, str], seed: int) -> tuple[str, str]:
    env = {**without_switches(), **env_extra}
    result = subprocess.run(
        [sys.executable, str(TESTS / "compiled_twin.py"), str(seed), "600"],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        check=True,
    )
    path, digest = result.stdout.split()
    return path, digest


@pytest.mark.skipif(not compiled_path.CHOICE.compiled, reason="the hot path was not compiled here")
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_every_session_sends_the_same_bytes_compiled_and_interpreted(seed: int) -> None:
    compiled = twin({}, seed)
    interpreted = twin({"USB2RC_NO_MYPYC": "1"}, seed)
    assert interpreted[0] == "interpreted"
    if compiled_path.CHOICE.reason is None:  # a source being edited runs interpreted both ways
        assert compiled[0] == "compiled"
    assert compiled[1] == interpreted[1]


def test_the_journey_digest_depends_on_the_journey() -> None:
    """The digest is not a constant: another seed, another journey, another digest."""
    assert twin({}, 1)[1] != twin({}, 2)[1]


@pytest.mark.parametrize("switch", ["USB2RC_NO_MYPYC", "USB2RC_PURE_PYTHON"])
def test_the_switch_loads_every_compiled_module_from_its_source(switch: str) -> None:
    code = (
        "import usb2rc.lines.driver as d, usb2rc.nodes.table as t, usb2rc.compiled_path as c;"
        "print(d.__file__, t.__file__); print(c.status())"
    )
    result = subprocess.run(
        [sys.executable, "-c", code],
        env={**without_switches(), switch: "1"},
        capture_output=True,
        text=True,
        check=True,
    )
    files, status = result.stdout.splitlines()
    assert all(name.endswith(".py") for name in files.split())
    assert status.startswith("hot path interpreted")
    if compiled_path.CHOICE.compiled:
        assert f"switched off ({switch})" in status


def test_a_source_changed_since_the_build_is_named_and_the_rest_stay_interpreted() -> None:
    module = "usb2rc.protocols.crc"
    digest = compiled_path.digest(compiled_path._source(module))
    assert compiled_path.why_interpreted({module: digest}, True, "") is None
    reason = compiled_path.why_interpreted({module: "x"}, True, "")
    assert reason is not None and module in reason and "pip install -e ." in reason
    assert compiled_path.why_interpreted({module: digest}, False, "") == (
        "their shared library was not built"
    )
    assert "USB2RC_NO_MYPYC" in str(compiled_path.why_interpreted({}, True, "USB2RC_NO_MYPYC"))


def test_without_the_sources_file_every_extension_beside_a_source_is_found() -> None:
    """What `choose()` loads from source when the file is missing (an interrupted build):
    every compiled module, none of the C loops (they have no source beside them)."""
    found = compiled_path.extensions_without_sources_file()
    assert found == sorted(compiled_path.CHOICE.compiled)
    assert not any(name.rsplit(".", 1)[-1].startswith("_") for name in found)


def test_the_sources_file_names_the_library_and_each_modules_hash() -> None:
    group, hashes = compiled_path.read_sources("group g\nusb2rc.a 11\nusb2rc.b 22\n")
    assert group == "g"
    assert hashes == {"usb2rc.a": "11", "usb2rc.b": "22"}


def test_the_finder_gives_the_source_of_the_modules_it_holds_and_nothing_else() -> None:
    source = compiled_path._source("usb2rc.protocols.crc")
    finder = compiled_path.SourceFirst({"usb2rc.protocols.crc": source})
    spec = finder.find_spec("usb2rc.protocols.crc", None)
    assert spec is not None and spec.origin == str(source)
    assert finder.find_spec("usb2rc.protocols.rc11", None) is None


@pytest.mark.skipif(not os.environ.get("CI"), reason="CI builds every compiled part")
def test_where_the_c_parts_are_built_the_hot_path_is_compiled_too() -> None:
    assert speedups.built(), "the C loops were not built (gcc and python3-dev missing?)"
    assert compiled_path.CHOICE.compiled, (
        "the C parts were built but mypyc's modules were not: see the install's output for "
        "'usb2rc: the hot path stays interpreted'"
    )
    if not any(os.environ.get(name) for name in ("USB2RC_NO_MYPYC", "USB2RC_PURE_PYTHON")):
        assert compiled_path.compiled_active(), compiled_path.status()
