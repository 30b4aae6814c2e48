"""A user's first hour from a wheel: build it, install it into a fresh venv, and run every
command README.md and docs/*.md show, from an empty folder.

The wheel is built with `pip wheel --no-deps` (build isolation: setuptools from the index)
and installed into a venv without system site-packages, its dependencies from the index. No
clone is on any path: the venv's `usb2rc` finds its configs, recordings and samples in the
installed package (`usb2rc example NAME`, `--replay demo`) or not at all. The command lists
and the way they run are tests/test_docs_commands.py's, so the two cannot drift apart.
"""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from test_docs_commands import run_offline_commands, run_root_commands

ROOT = Path(__file__).resolve().parent.parent

pytestmark = pytest.mark.slow  # builds a wheel and installs its dependencies: ~1 min


def _run(*argv: str | Path, cwd: Path) -> None:
    result = subprocess.run(
        [str(a) for a in argv], cwd=cwd, capture_output=True, text=True, timeout=600, check=False
    )
    assert result.returncode == 0, f"{argv}: exit {result.returncode}\n{result.stderr[-3000:]}"


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """(the built wheel, the venv's usb2rc program)."""
    work = tmp_path_factory.mktemp("wheel")
    _run(
        sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", ROOT, "-w", work / "dist", cwd=work
    )
    wheel = next((work / "dist").glob("usb2rc-*.whl"))
    _run(sys.executable, "-m", "venv", work / "venv", cwd=work)
    _run(work / "venv" / "bin" / "python", "-m", "pip", "install", "-q", wheel, cwd=work)
    return wheel, work / "venv" / "bin" / "usb2rc"


def test_every_documented_command_runs_from_an_empty_folder(
    installed: tuple[Path, Path], tmp_path: Path
) -> None:
    _, usb2rc = installed
    failures = run_offline_commands([str(usb2rc)], tmp_path)
    assert not failures, "\n\n".join(failures)


def test_root_commands_run_from_the_wheel(installed: tuple[Path, Path], tmp_path: Path) -> None:
    _, usb2rc = installed
    (tmp_path / "cwd").mkdir()
    failures = run_root_commands([str(usb2rc)], tmp_path, tmp_path / "cwd")
    assert not failures, "\n\n".join(failures)


def test_the_venv_sees_no_clone(installed: tuple[Path, Path], tmp_path: Path) -> None:
    _, usb2rc = installed
    python = usb2rc.parent / "python"
    result = subprocess.run(
        [python, "-c", "import usb2rc; print(usb2rc.__file__)"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    assert str(ROOT) not in result.stdout  # the installed package, not the source tree


def test_the_wheel_carries_the_mit_license(installed: tuple[Path, Path]) -> None:
    wheel, _ = installed
    with zipfile.ZipFile(wheel) as archive:
        names = archive.namelist()
        metadata = archive.read(next(n for n in names if n.endswith(".dist-info/METADATA")))
        license_text = archive.read(next(n for n in names if n.endswith("licenses/LICENSE")))
    assert b"License-Expression: MIT" in metadata
    assert b"MIT License" in license_text and b"the usb2rc authors" in license_text
