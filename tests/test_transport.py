"""SerialLink: a slow or failing open never blocks the caller (the scheduler's tick)."""

from __future__ import annotations

import threading

import serial

from usb2rc import transport
from usb2rc.transport import LineEvent, SerialLink


def test_a_slow_open_runs_aside_and_is_reported_once(monkeypatch):
    release = threading.Event()
    entered = threading.Event()
    real_open = serial.serial_for_url

    def slow_open(url, **kwargs):
        entered.set()
        assert release.wait(10), "never released"
        return real_open("loop://", **kwargs)

    monkeypatch.setattr(transport.serial, "serial_for_url", slow_open)
    link = SerialLink("slow://", reopen_interval_s=0.0)
    assert link.try_open() is False  # returns at once although the open is still going on
    assert entered.wait(10)
    assert not link.is_open and link.try_open() is False  # one opener at a time
    release.set()
    link._opener.join(10)
    assert link.is_open
    assert link.line_event() is LineEvent.OPENED and link.line_event() is None
    assert link.write(b"H-").sent == 2 and link.stats.opens == 1
    link.close()


def test_a_failing_open_is_logged_once_with_what_to_do(monkeypatch, caplog):
    def missing(url, **kwargs):
        raise serial.SerialException(f"[Errno 2] could not open port {url}: No such file")

    monkeypatch.setattr(transport.serial, "serial_for_url", missing)
    link = SerialLink("/dev/ttyUSB9", reopen_interval_s=0.0)
    assert link.open_now() is False
    for _ in range(3):
        link.try_open()
        link._opener.join(10)
    errors = [r.message for r in caplog.records if "ttyUSB9" in r.message]
    assert len(errors) == 1 and "--port" in errors[0]
    assert link.line_event() is None
