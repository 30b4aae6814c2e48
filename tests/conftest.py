"""Fixtures shared by the tests: a pty line, a replay folder; and around every test, a private
runtime folder and the guarantee that no process it started outlives it."""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

import process_harness
import pytest
from daemon_harness import PtyLine
from hypothesis import HealthCheck, settings

from usb2rc import compiled_path

# Property tests: no deadline per example, no "too slow" health check. On a loaded host an
# example that takes 10 ms alone can take more than hypothesis's 200 ms, and hypothesis
# then fails the test as flaky (seen beside CPU hogs). What a test must do in time, it
# asserts itself.
settings.register_profile(
    "loaded-host", deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
settings.load_profile("loaded-host")


def pytest_configure(config: pytest.Config) -> None:
    process_harness.become_subreaper()


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """A test marked `interpreted` wraps or swaps a part of a hot-path class, which a
    compiled class does not allow: it runs where the hot path is interpreted (CI's second
    pass sets USB2RC_NO_MYPYC=1), and says why it is skipped where it is compiled."""
    if not compiled_path.compiled_active():
        return
    skip = pytest.mark.skip(
        reason="reaches into a compiled hot-path class: runs with USB2RC_NO_MYPYC=1"
    )
    for item in items:
        if item.get_closest_marker("interpreted") is not None:
            item.add_marker(skip)


def pytest_sessionstart(session: pytest.Session) -> None:
    """Say so when usb2rc processes from elsewhere write to ptys: a test's pty may be given
    a path one of them opens again (their frames on its line, its port locked)."""
    if hasattr(session.config, "workerinput"):  # an xdist worker: the main process says it
        return
    outside = process_harness.pty_writers_outside()
    reporter = session.config.pluginmanager.get_plugin("terminalreporter")
    if outside and reporter is not None:
        reporter.write_line(
            f"warning: {len(outside)} usb2rc process(es) outside this test run write to ptys; "
            "a test's pty may get a path they open again (stop them if they are leftovers):",
            yellow=True,
        )
        for pid, command in sorted(outside.items()):
            reporter.write_line(f"  pid {pid}: {command}")


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(
    item: pytest.Item, call: pytest.CallInfo[None]
) -> Iterator[None] | pytest.TestReport:
    """A failing test's report ends with the last lines of each daemon log it made: what
    the daemon did is most of what a failure on a loaded host says."""
    report: pytest.TestReport = yield
    if report.failed:
        for log in process_harness.logs:
            report.sections.append((f"daemon log {log} (last lines)", tail(log)))
    return report


def tail(path: Path, lines: int = 60) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError as exc:
        return f"(unreadable: {exc})"


@pytest.fixture(autouse=True)
def no_process_outlives_its_test(own_environment: Path) -> Iterator[None]:
    """After the test, pass or fail: the harness's daemons it left running are stopped, and
    anything else it started and left running is ended and fails the test (a `finally` or a
    fixture of its own should have stopped it). Before the runtime folder goes."""
    before = process_harness.descendants()
    process_harness.logs.clear()
    yield
    process_harness.stop_owned()
    left = process_harness.still_running(process_harness.descendants() - before)
    commands = {pid: process_harness.command_line(pid) for pid in left}
    process_harness.end(left)
    process_harness.reap(keep=before)
    if commands:
        listed = "\n".join(f"  pid {pid}: {command}" for pid, command in commands.items())
        pytest.fail(f"the test left these running (now ended):\n{listed}", pytrace=False)


@pytest.fixture(autouse=True)
def own_environment(monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """An environment of the test's own, whichever pytest worker runs it (pytest-xdist):

    - XDG_RUNTIME_DIR: a daemon's default status socket (and whatever else goes there) is
      no other test's, nor the machine's, when tests run side by side. Short
      (/tmp/xdg-XXXXXXXX): a unix socket's path has at most 107 bytes.
    - no COLUMNS / LINES: xdist sets them (80 x 24) in its workers, and a command a test runs
      in a terminal of another size (tmux) would take them over the terminal's own.
    """
    folder = Path(tempfile.mkdtemp(prefix="xdg-", dir="/tmp"))
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(folder))
    monkeypatch.delenv("COLUMNS", raising=False)
    monkeypatch.delenv("LINES", raising=False)
    yield folder
    shutil.rmtree(folder, ignore_errors=True)


@pytest.fixture
def line() -> Iterator[PtyLine]:
    pty = PtyLine()
    yield pty
    pty.close_at_the_end()


@pytest.fixture
def replay_dir(tmp_path: Path) -> Path:
    folder = tmp_path / "replay"
    folder.mkdir()
    return folder
