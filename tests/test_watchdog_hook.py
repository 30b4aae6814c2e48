"""The watchdog hook: fed while every output ticks, starved when one scheduler hangs."""

from __future__ import annotations

import threading

from usb2rc.configfile import Config, OutputConfig
from usb2rc.daemon import Daemon
from usb2rc.hid.replay import ReplayBackend


class Hung:
    """A session whose ticks fail; the rest is the session it wraps."""

    def __init__(self, session):
        self.session = session

    def __getattr__(self, name):
        return getattr(self.session, name)

    def tick(self, now, snapshot):
        raise RuntimeError("the SUMD session hangs")


def test_watchdog_starves_when_one_output_stops_ticking(tmp_path, monkeypatch):
    config = Config(
        outputs=(
            OutputConfig(protocol="c2-16b", port="loop://"),
            OutputConfig(
                protocol="sumd", port="loop://", rate_hz=100, channels=("node0.x", "node0.y")
            ),
        )
    )
    fed = threading.Event()
    daemon = Daemon(config, ReplayBackend(tmp_path), on_tick=fed.set)
    daemon.start()
    try:
        assert fed.wait(5), "never fed while both outputs tick"
        c2, sumd_out = (out.driver for out in daemon.outputs)

        # SUMD ticks no more: its driver's session (compiled: its `tick` cannot be
        # swapped) in a wrapper whose ticks fail
        monkeypatch.setattr(sumd_out, "session", Hung(sumd_out.session))
        ticks_before = c2.stats.ticks
        # once the SUMD output has been silent for a second, the C2 ticks stop feeding
        deadline_ticks = ticks_before + 60  # 1.2 s of 20 ms ticks
        while c2.stats.ticks < deadline_ticks:
            fed.clear()
            threading.Event().wait(0.05)
        fed.clear()
        ticks_mark = c2.stats.ticks
        while c2.stats.ticks < ticks_mark + 10:
            threading.Event().wait(0.02)
        assert not fed.is_set(), "fed although one output stopped ticking"
        assert daemon.drivers.is_alive() and sumd_out.stats.tick_errors > 0
    finally:
        daemon.stop()


def test_a_failing_tick_is_counted_not_fatal_and_starves_the_watchdog(tmp_path, caplog):
    # one SUMD channel is below the protocol's minimum: every SUMD tick raises in the encoder
    config = Config(
        outputs=(OutputConfig(protocol="sumd", port="loop://", rate_hz=100, channels=("node0.x",)),)
    )
    fed = threading.Event()
    daemon = Daemon(config, ReplayBackend(tmp_path), on_tick=fed.set)
    daemon.start()
    try:
        sumd_out = daemon.outputs[0].driver
        while sumd_out.stats.tick_errors < 20:
            threading.Event().wait(0.02)
        assert daemon.drivers.is_alive()
        assert not fed.is_set()
    finally:
        daemon.stop()
    assert sum("tick failed" in r.message for r in caplog.records) == 1  # logged once
