"""End to end (issue 15's "done when"): C2-16B, SUMD, CRSF and SBUS outputs on real ptys and
a MAVLink output on UDP, all five at once, the daemon as a subprocess over two replayed
devices; each far end decodes the mapped values, an unplug shows each protocol's failsafe
(docs/ICD.md: C2-16B `!`, SUMD 0x81, SBUS frame-lost + failsafe flags, CRSF no frames,
MAVLink every override channel released, then heartbeats only), a replug brings each back.
CRSF and SBUS are read with the tests' own decoder (rc_reference.py), MAVLink with
pymavlink's parser (daemon_harness.MavlinkStream); the CRSF far end plays an ELRS module that
answers with link statistics and timing corrections."""

from __future__ import annotations

import re
import signal
import struct
import time
from pathlib import Path
from typing import Any

from daemon_harness import (
    RELEASED,
    PtyLine,
    StickState,
    UdpLine,
    channels,
    data_frames,
    expected_frame,
    install,
    of_type,
    pwm_of_int16,
    recording,
    run_daemon,
)
from rc_reference import RefCrsfFrame, RefSbusFrame, crsf_frame, rc11

from usb2rc.protocols.c2_16b import codec as c2_16b
from usb2rc.protocols.sumd import codec as sumd

WAIT_S = 20.0
STICK_A = [StickState(), StickState(x=0, y=16383, slider=40, buttons=1)]
STICK_B = [StickState(), StickState(rz=200, buttons=0)]
CHANNELS = ["node0.x", "node0.y", "node1.rz", "node0.slider", "node0.button1"]


def rc11_expected(a: StickState, b: StickState) -> list[int]:
    """The five listed channels as 11-bit values, from the documented scalings."""
    axes_a, group1_a, _ = expected_frame(a)
    axes_b, _, _ = expected_frame(b)
    button = 1811 if group1_a & 1 else 172
    return [rc11(axes_a[0]), rc11(axes_a[1]), rc11(axes_b[6]), rc11(axes_a[3]), button]


def sumd_expected(a: StickState, b: StickState) -> list[int]:
    def axis(v: int) -> int:  # docs/ICD.md, "SUMD (HoTT) output"
        return 8800 + (2 * (v + 32768) * 6400 + 65535) // (2 * 65535)

    axes_a, group1_a, _ = expected_frame(a)
    axes_b, _, _ = expected_frame(b)
    button = 15200 if group1_a & 1 else 8800
    return [axis(axes_a[0]), axis(axes_a[1]), axis(axes_b[6]), axis(axes_a[3]), button]


def override_expected(a: StickState, b: StickState) -> list[int]:
    """The five listed channels as RC_CHANNELS_OVERRIDE µs (1000..2000, buttons 1000/2000),
    the other 13 "ignore this field" (65535)."""
    axes_a, group1_a, _ = expected_frame(a)
    axes_b, _, _ = expected_frame(b)
    button = 2000 if group1_a & 1 else 1000
    axes = [axes_a[0], axes_a[1], axes_b[6], axes_a[3]]
    return [*map(pwm_of_int16, axes), button] + [65535] * 13


def last_override(messages: list[Any]) -> list[int] | None:
    overrides = of_type(messages, "RC_CHANNELS_OVERRIDE")
    return channels(overrides[-1]) if overrides else None


class FakeModule(PtyLine):
    """An ELRS transmitter module's UART: after every 25th RC frame it answers with link
    statistics and a timing correction (250 Hz, offset 0), as frames built from the
    description."""

    def __init__(self) -> None:
        super().__init__("crsf")
        self.rc_frames = 0

    def _received(self, now: float, data: bytes, frames: list[Any]) -> None:
        super()._received(now, data, frames)
        for frame in frames:
            self.rc_frames += frame.type == 0x16
            if frame.type == 0x16 and self.rc_frames % 25 == 0:
                link = bytes([40, 42, 100, 10, 0, 6, 3, 50, 99, 8])
                timing = bytes([0xEA, 0xEE, 0x10]) + struct.pack(">Ii", 40000, 0)
                self.send(crsf_frame(0xEA, 0x14, link) + crsf_frame(0xEA, 0x3A, timing))


def config(
    tmp_path: Path, c2: PtyLine, sumd_line: PtyLine, crsf: PtyLine, sbus: PtyLine, udp: UdpLine
) -> Path:
    listed = "[" + ", ".join(CHANNELS) + "]"
    path = tmp_path / "five.yaml"
    path.write_text(
        "outputs:\n"
        f"  - {{protocol: c2-16b, port: {c2.path}}}\n"
        f"  - {{protocol: sumd, port: {sumd_line.path}, channels: {listed}}}\n"
        f"  - {{protocol: crsf, port: {crsf.path}, channels: {listed}}}\n"
        f"  - {{protocol: sbus, port: {sbus.path}, channels: {listed}}}\n"
        f"  - {{protocol: mavlink, port: '{udp.url}', channels: {listed}}}\n"
        "devices:\n"
        "  - {name: a, match: {port: replay-a}, node_id: 0}\n"
        "  - {name: b, match: {port: replay-b}, node_id: 1}\n"
    )
    return path


def crsf_rc(frames: list[Any]) -> list[RefCrsfFrame]:
    return [f for f in frames if f.type == 0x16]


def latest_state(line: PtyLine, wanted: Any, kind: type, key: Any) -> Any:
    """Wait until the last frame of `kind` has key(frame) == wanted."""
    return line.wait_for(
        lambda fr: (
            [f for f in fr if isinstance(f, kind)][-1:]
            and key([f for f in fr if isinstance(f, kind)][-1]) == wanted
        ),
        WAIT_S,
    )


def test_five_outputs_map_fail_safe_and_come_back(tmp_path: Path, line: PtyLine, replay_dir):
    sumd_line, crsf_line, sbus_line = PtyLine("sumd"), FakeModule(), PtyLine("sbus")
    udp = UdpLine()
    lines: list[PtyLine] = [sumd_line, crsf_line, sbus_line, udp]
    install(replay_dir / "a.hid", recording(STICK_A))
    install(replay_dir / "b.hid", recording(STICK_B))
    path = config(tmp_path, line, sumd_line, crsf_line, sbus_line, udp)
    daemon = run_daemon(tmp_path, line.path, replay_dir, "--config", str(path))
    live = rc11_expected(STICK_A[-1], STICK_B[-1])
    override = override_expected(STICK_A[-1], STICK_B[-1])
    try:
        # every far end decodes the mapped values of both devices
        line.wait_for(
            lambda fr: (
                (f := data_frames(fr, 1)[-1:]) and f[0].axes == expected_frame(STICK_B[-1])[0]
            ),
            WAIT_S,
        )
        latest_state(
            sumd_line,
            (False, sumd_expected(STICK_A[-1], STICK_B[-1])),
            sumd.SumdFrame,
            lambda f: (f.failsafe, list(f.channels)[:5]),
        )
        crsf_line.wait_for(lambda fr: (rc := crsf_rc(fr)) and rc[-1].channels[:5] == live, WAIT_S)
        assert crsf_rc(crsf_line.frames())[-1].channels[5:] == [172] * 11
        assert {f.address for f in crsf_rc(crsf_line.frames())} == {0xEE}
        latest_state(
            sbus_line,
            (False, False, live),
            RefSbusFrame,
            lambda f: (f.frame_lost, f.failsafe, f.channels[:5]),
        )
        udp.wait_for(lambda ms: last_override(ms) == override, WAIT_S)
        live_override = of_type(udp.frames(), "RC_CHANNELS_OVERRIDE")[-1]
        assert (live_override.target_system, live_override.target_component) == (1, 1)
        assert of_type(udp.frames(), "HEARTBEAT")  # a GCS heartbeat at 1 Hz

        # the module's replies: link quality and timing reach the stats
        crsf_line.wait_for(lambda fr: len(crsf_rc(fr)) >= 60, WAIT_S)
        daemon.signal(signal.SIGUSR1)
        stats = wait_log(daemon, re.compile(r"output3-crsf .*link quality 100% up / 99% down"))
        assert "following the module: 250 Hz" in stats

        # unplug device b (node 1): each protocol's failsafe
        (replay_dir / "b.hid").unlink()
        line.wait_for(
            lambda fr: (f := data_frames(fr, 1)[-1:]) and f[0].status == c2_16b.FAILSAFE, WAIT_S
        )
        sumd_line.wait_for(lambda fr: [f for f in fr if f.failsafe][-1:], WAIT_S)
        sbus_at = len(
            sbus_line.wait_for(
                lambda fr: fr if fr[-1].failsafe and fr[-1].frame_lost else None, WAIT_S
            )
        )
        crsf_at = len(crsf_rc(crsf_line.frames()))
        # 30 SBUS frames (0.3 s) later, CRSF has sent at most the tick that was under way
        sbus_line.wait_for(lambda fr: len(fr) >= sbus_at + 30, WAIT_S)
        assert all(f.failsafe and f.frame_lost for f in sbus_line.frames()[sbus_at:])
        assert len(crsf_rc(crsf_line.frames())) <= crsf_at + 1
        # MAVLink: every override channel released to the RC radio for 1 s, then heartbeats
        udp.wait_for(lambda ms: last_override(ms) == RELEASED, WAIT_S)
        udp.wait_for(lambda ms: len(of_type(ms[-2:], "HEARTBEAT")) == 2, WAIT_S)
        mavlink_at = len(udp.frames())
        daemon.signal(signal.SIGUSR1)
        wait_log(daemon, re.compile(r"output3-crsf .*frames withheld \(failsafe\) [1-9]"))
        wait_log(daemon, re.compile(r"output5-mavlink .*releases [1-9]"))

        # replug: every output live again with the mapped values
        install(replay_dir / "b.hid", recording(STICK_B))
        # (the replug replays the recording from its first state: wait for the last one)
        crsf_line.wait_for(
            lambda fr: (rc := crsf_rc(fr)[crsf_at + 1 :]) and rc[-1].channels[:5] == live, WAIT_S
        )
        # back at its own rate (250 Hz), not the 20 ms grid of its silent ticks: over 30 of
        # SBUS's frames (100 Hz, the same thread) CRSF sends ~2.5 times as many; more than
        # 1.5 times (a CRSF output that kept the 20 ms grid sent as many as SBUS)
        crsf_live_at, sbus_live_at = len(crsf_rc(crsf_line.frames())), len(sbus_line.frames())
        sbus_line.wait_for(lambda fr: len(fr) >= sbus_live_at + 30, WAIT_S)
        crsf_sent = len(crsf_rc(crsf_line.frames())) - crsf_live_at
        sbus_sent = len(sbus_line.frames()) - sbus_live_at
        assert 2 * crsf_sent > 3 * sbus_sent, (crsf_sent, sbus_sent)
        latest_state(
            sbus_line,
            (False, False, live),
            RefSbusFrame,
            lambda f: (f.frame_lost, f.failsafe, f.channels[:5]),
        )
        latest_state(sumd_line, False, sumd.SumdFrame, lambda f: f.failsafe)
        udp.wait_for(lambda ms: last_override(ms[mavlink_at:]) == override, WAIT_S)
        line.wait_for(
            lambda fr: (f := data_frames(fr, 1)[-1:]) and f[0].status == c2_16b.LIVE, WAIT_S
        )
    finally:
        code = daemon.stop()
        for pty in lines:
            pty.close()
    assert code == 0, daemon.log()
    assert "Traceback" not in daemon.log()


def wait_log(daemon: Any, pattern: re.Pattern[str]) -> str:
    deadline = time.monotonic() + WAIT_S
    while not pattern.search(text := daemon.log()):
        if daemon.proc.poll() is not None or time.monotonic() > deadline:
            raise AssertionError(f"{pattern.pattern!r} not in the log:\n{text[-3000:]}")
        time.sleep(0.05)
    return text


def test_monitor_with_outputs_shows_the_module_link_quality(tmp_path: Path, replay_dir):
    from usb2rc.commands import monitor
    from usb2rc.configfile import load_config_text
    from usb2rc.hid.replay import ReplayBackend

    module = FakeModule()
    install(replay_dir / "a.hid", recording(STICK_A))
    config = load_config_text(
        f"outputs:\n  - {{protocol: crsf, port: {module.path}, channels: [node0.x, node0.y]}}\n"
    )
    side = monitor.InputSide(config, ReplayBackend(str(replay_dir)), outputs=True)
    side.start()
    try:
        deadline = time.monotonic() + WAIT_S
        while "link quality 100% up" not in (text := monitor.snapshot_text(side.snapshot(), [])):
            assert time.monotonic() < deadline, text
            time.sleep(0.05)
        assert f"outputs on {module.path}" in text
        assert "following the module: 250 Hz" in text
    finally:
        side.stop()
        module.close()
