"""Fixtures shared by the daemon tests: a pty line and a replay folder."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from daemon_harness import PtyLine


@pytest.fixture
def line() -> Iterator[PtyLine]:
    pty = PtyLine()
    yield pty
    pty.close()


@pytest.fixture
def replay_dir(tmp_path: Path) -> Path:
    folder = tmp_path / "replay"
    folder.mkdir()
    return folder
