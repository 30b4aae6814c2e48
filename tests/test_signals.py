"""usb2rc.service.signals and the main loop (commands/run.serve) in-process, handlers called
directly.

Nothing here installs a handler in the test process: `DaemonSignals.handle` is what the
kernel's signal would run, so the tests call it themselves, at the moments they pick.
The real signals on the real process are in test_daemon_signals.py.
"""

from __future__ import annotations

import logging
import signal
import sys
import weakref
from collections.abc import Callable

import pytest

from usb2rc.commands import run
from usb2rc.daemon import ReloadResult
from usb2rc.service.signals import DaemonSignals, Phase, ReloadAbandoned


def test_a_stop_while_starting_exits_0_at_once_and_ignores_the_rest():
    signals = DaemonSignals()
    with pytest.raises(SystemExit) as stop:
        signals.handle(signal.SIGTERM)
    assert stop.value.code == 0
    for signum in (signal.SIGHUP, signal.SIGINT, signal.SIGTERM, signal.SIGUSR1):
        signals.handle(signum)  # no second SystemExit in the middle of the first one's unwinding
    assert signals.take_ignored() == ["SIGHUP", "SIGINT", "SIGTERM", "SIGUSR1"]
    assert signals.take_ignored() == []


def test_reload_and_stats_while_starting_wait_for_the_main_loop():
    signals = DaemonSignals()
    signals.handle(signal.SIGHUP)
    signals.handle(signal.SIGUSR1)
    assert signals.phase is Phase.STARTING
    assert [signals.requests.get_nowait(), signals.requests.get_nowait()] == ["reload", "stats"]


@pytest.mark.parametrize("stop", [signal.SIGTERM, signal.SIGINT])
def test_a_stop_while_running_is_a_request_and_then_everything_is_ignored(stop):
    signals = DaemonSignals()
    signals.running()
    signals.handle(stop)  # no SystemExit: the main loop stops the daemon itself
    assert signals.stop_requested
    assert signals.requests.get_nowait() == "stop"
    signals.handle(signal.SIGHUP)
    signals.handle(stop)
    assert signals.requests.empty()
    assert signals.take_ignored() == ["SIGHUP", stop.name]


class FakeDaemon:
    """What serve() needs of a Daemon; `on_start` / `on_stop` stand for signals arriving then."""

    def __init__(self) -> None:
        self.on_start: Callable[[], None] = lambda: None
        self.on_stop: Callable[[], None] = lambda: None
        self.on_reload: Callable[[], None] = lambda: None
        self.calls: list[str] = []

    def start(self) -> None:
        self.calls.append("start")
        self.on_start()

    def stop(self) -> None:
        self.calls.append("stop")
        self.on_stop()

    port_override = "loop://"  # the configs here leave the port to --port

    def prepare_reload(self, config: object) -> object:
        return config

    def apply_reload(self, _prepared: object) -> ReloadResult:
        self.calls.append("reload")
        self.on_reload()
        return ReloadResult(taken=True, outputs_changed=False)

    def stats_lines(self) -> list[str]:
        return []


def serve(daemon: FakeDaemon, signals: DaemonSignals, config_path: str | None = None) -> int:
    return run.serve(daemon, config_path, 0.0, None, signals)  # type: ignore[arg-type]


def test_signals_while_stopping_are_logged_and_ignored(caplog):
    daemon, signals = FakeDaemon(), DaemonSignals()
    daemon.on_start = lambda: signals.handle(signal.SIGTERM)

    def more_signals() -> None:
        for signum in (signal.SIGHUP, signal.SIGHUP, signal.SIGINT, signal.SIGTERM):
            signals.handle(signum)

    daemon.on_stop = more_signals
    with caplog.at_level(logging.INFO, logger="usb2rc"):
        assert serve(daemon, signals) == 0
    assert daemon.calls == ["start", "stop"]
    lines = [r.getMessage() for r in caplog.records]
    assert "SIGHUP while stopping: ignored (2 times)" in lines
    assert "SIGINT while stopping: ignored" in lines
    assert lines[-1] == "stopped"


def test_a_reload_queued_just_before_a_stop_does_not_run(tmp_path):
    """CPython runs pending handlers in signal-number order: SIGHUP (1) before SIGTERM (15),
    whatever order they came in. Once a stop is asked for, the loop only stops."""
    config = tmp_path / "c.yaml"
    config.write_text("defaults: true\n")
    daemon, signals = FakeDaemon(), DaemonSignals()

    def both_pending() -> None:
        signals.handle(signal.SIGHUP)
        signals.handle(signal.SIGTERM)

    daemon.on_start = both_pending
    assert serve(daemon, signals, str(config)) == 0
    assert daemon.calls == ["start", "stop"]


def test_a_reload_before_the_stop_runs(tmp_path):
    config = tmp_path / "c.yaml"
    config.write_text("defaults: true\n")
    daemon, signals = FakeDaemon(), DaemonSignals()
    signals.handle(signal.SIGHUP)  # while starting: kept for the main loop
    daemon.on_reload = lambda: signals.handle(signal.SIGTERM)
    assert serve(daemon, signals, str(config)) == 0
    assert daemon.calls == ["start", "reload", "stop"]


def test_serve_leaves_the_stopping_phase_on_an_error():
    daemon, signals = FakeDaemon(), DaemonSignals()

    def broken() -> None:
        raise RuntimeError("a bug in the loop")

    daemon.on_start = lambda: signals.handle(signal.SIGUSR1)
    daemon.stats_lines = broken  # type: ignore[method-assign]
    with pytest.raises(RuntimeError):
        serve(daemon, signals)
    assert daemon.calls == ["start", "stop"]
    assert signals.stop_requested  # a signal during that stop is ignored, not fatal


def test_a_start_up_stop_swallowed_by_a_callback_still_stops_before_the_start(monkeypatch):
    """A SystemExit raised inside a callback (here a weakref's; in the wild, importlib's
    module-lock one) is reported by Python, not raised: the stop must not get lost."""
    signals = DaemonSignals()
    reported: list[object] = []
    monkeypatch.setattr(signals, "_previous_unraisablehook", reported.append)
    monkeypatch.setattr(sys, "unraisablehook", signals._unraisable)

    class Thing:
        pass

    thing, other = Thing(), Thing()
    ref = weakref.ref(thing, lambda _r: signals.handle(signal.SIGTERM))
    del thing  # the callback runs now; its SystemExit goes to the unraisable hook
    assert ref() is None
    assert reported == []  # our own stop: no "Exception ignored" noise in the log
    ref_other = weakref.ref(other, lambda _r: int("not a number"))
    del other
    assert ref_other() is None
    assert len(reported) == 1  # anything else is still reported
    daemon = FakeDaemon()
    assert serve(daemon, signals) == 0
    assert daemon.calls == []  # never started


def test_cpythons_race_report_while_stopping_is_one_more_ignored_signal(monkeypatch):
    """CPython reports a signal that its C handler caught after the Python handler had gone
    (SIG_IGN at exit) as `OSError: Signal 15 ignored due to race condition`, through the
    unraisable hook. While stopping that is what happens to every signal: noted, no traceback.
    Before a stop, or any other OSError, it is reported as usual."""
    signals = DaemonSignals()
    reported: list[object] = []
    monkeypatch.setattr(signals, "_previous_unraisablehook", reported.append)
    monkeypatch.setattr(sys, "unraisablehook", signals._unraisable)

    def report(message: str) -> None:
        class Dropping:
            def __del__(self) -> None:
                raise OSError(message)

        Dropping()  # its __del__ raises now; CPython hands the OSError to the hook

    report("Signal 15 ignored due to race condition")
    assert len(reported) == 1  # not stopping: as CPython would print it
    signals.stopping()
    report("Signal 15 ignored due to race condition")
    report("Signal 1 ignored due to race condition")
    assert len(reported) == 1
    assert signals.take_ignored() == ["SIGTERM", "SIGHUP"]
    report("[Errno 5] Input/output error")
    assert len(reported) == 2


# --- a stop preempts a reload (issue 19, point 5; docs/ICD.md, "Stop") -----------------------


def running_signals() -> DaemonSignals:
    signals = DaemonSignals()
    assert signals.running()
    return signals


@pytest.mark.parametrize("stop", [signal.SIGTERM, signal.SIGINT])
def test_a_stop_inside_a_reload_abandons_it_where_it_is(stop):
    signals = running_signals()
    reached = []
    with pytest.raises(ReloadAbandoned), signals.abandoned_on_stop():
        signals.handle(stop)
        reached.append("after the stop")
    assert reached == []
    assert signals.stop_requested and signals.requests.get_nowait() == "stop"


def test_a_stop_before_a_reload_abandons_it_before_it_starts():
    signals = running_signals()
    signals.handle(signal.SIGTERM)
    with pytest.raises(ReloadAbandoned), signals.abandoned_on_stop():
        pytest.fail("the reload ran after the stop")


def test_outside_a_reload_a_stop_is_a_request_and_other_signals_never_abandon():
    signals = running_signals()
    with signals.abandoned_on_stop():
        signals.handle(signal.SIGHUP)
        signals.handle(signal.SIGUSR1)
    signals.handle(signal.SIGTERM)  # after the reload: no exception, the loop reads it
    assert [signals.requests.get_nowait() for _ in range(3)] == ["reload", "stats", "stop"]


def test_the_entry_point_blocks_exactly_the_signals_the_daemon_handles():
    """usb2rc/__main__.py blocks them before it can import this module; the handlers unblock
    them. One left out there could kill a starting daemon; one too many would stay blocked."""
    import usb2rc.__main__ as entry
    from usb2rc.service.signals import REQUESTS

    assert set(entry.HELD_UNTIL_HANDLED) == set(REQUESTS)
