"""Faults on the running daemon: the serial line vanishing, read errors, RX garbage and
requests, SIGHUP with good and bad configs, unusable devices, the SUMD output."""

from __future__ import annotations

import itertools
import os
import random
import signal

from daemon_harness import (
    INVERT_UNGUARDED_X_CONFIG,
    PtyLine,
    StickState,
    data_frames,
    expected_frame,
    install,
    recording,
    run_daemon,
    service_frames,
    services,
)

from usb2rc.protocols.c2_16b import codec as c2_16b
from usb2rc.protocols.sumd import codec as sumd

LIVE, FAILSAFE = c2_16b.LIVE, c2_16b.FAILSAFE


def live_node(frames: list, node_id: int = 0) -> bool:
    own = data_frames(frames, node_id)
    return bool(own) and own[-1].status == LIVE


def test_serial_port_gone_and_back(tmp_path, replay_dir):
    install(replay_dir / "stick.hid", recording([StickState(), StickState(x=0)]))
    link = tmp_path / "ttyLINK"  # the port path the daemon knows; we swap what is behind it
    first = PtyLine()
    link.symlink_to(first.path)
    daemon = run_daemon(tmp_path, str(link), replay_dir)
    second = None
    try:
        first.wait_for(lambda fr: len(data_frames(fr, 0)) >= 5)
        link.unlink()
        first.close()  # the adapter is pulled: writes fail, the path is gone
        second = PtyLine()
        link.symlink_to(second.path)  # ... and plugged back in
        second.wait_for(lambda fr: live_node(fr), timeout=10)
        frames = second.frames()
        assert frames[0].service == c2_16b.Service.STARTUP  # resumes with the startup frame
        assert services(frames, 0)[:4] == ["connected", "vid-pid", "device-string", "device-type"]
        codes = [f.code for f in data_frames(frames, 0)]
        assert all(b == (a + 1) % 256 for a, b in itertools.pairwise(codes))
    finally:
        assert daemon.stop() == 0
        if second is not None:
            second.close()
    log = daemon.log()
    assert "Traceback" not in log
    assert log.count("lost") == 1 and "is back" in log


def after_error(frames: list, node_id: int = 0) -> list:
    """The frames from node_id's first ERROR service frame on (none while there is none)."""
    for index, frame in enumerate(frames):
        if (
            isinstance(frame, c2_16b.ServiceFrame)
            and frame.node_id == node_id
            and frame.service == c2_16b.Service.ERROR
        ):
            return frames[index:]
    return []


def test_device_read_error_mid_stream(tmp_path, line, replay_dir):
    states = [StickState(), *[StickState(x=0, buttons=1)] * 3]
    text = recording(states, extra="# usb2rc-fault: read-error at 0.5")
    install(replay_dir / "bad.hid", text)
    daemon = run_daemon(tmp_path, line.path, replay_dir)
    try:
        line.wait_for(lambda fr: "error" in services(fr, 0))
        # Still plugged: it is opened again (on the next hot-plug scan, which may come before
        # the next frame) and comes back live with a connect sequence.
        line.wait_for(
            lambda fr: "connected" in services(after_error(fr), 0) and live_node(after_error(fr))
        )
        after = after_error(line.frames())
        assert after[0].error_code == 0x01  # READ_FAILED
        assert services(after, 0)[:3] == ["error", "disconnected", "connected"]
        # From the error until the node is live again, every frame is `!` with failsafe values
        # (no button pressed), through the reopen's re-announcement and its neutral guard.
        own = data_frames(after, 0)
        first_live = next(i for i, f in enumerate(own) if f.status == LIVE)
        assert first_live > 0
        assert all(f.status == FAILSAFE and f.group1 == 0 for f in own[:first_live])
    finally:
        assert daemon.stop() == 0
    assert "Traceback" not in daemon.log()


def test_rx_garbage_and_requests(tmp_path, line, replay_dir):
    install(replay_dir / "stick.hid", recording([StickState()]))
    daemon = run_daemon(tmp_path, line.path, replay_dir)
    try:
        line.wait_for(lambda fr: live_node(fr))
        rng = random.Random(7)
        garbage = bytes(rng.randrange(256) for _ in range(300)).replace(b"H", b"h")
        request = c2_16b.encode_data(c2_16b.CONFIG_REQUEST, 0x10, 0, [0] * 10, 0, 0)
        poll_present = c2_16b.poll_request(0)
        poll_absent = c2_16b.poll_request(9)
        count = len(line.frames())
        line.send(garbage + request + garbage[:50] + poll_present + garbage[50:90] + poll_absent)
        line.wait_for(lambda fr: "disconnected" in services(fr[count:], 9))
        line.wait_for(lambda fr: "device-type" in services(fr[count:], 0))
        # `<` and `4` for node 0 arrived in one tick: the sequence owed once is sent once
        line.wait_for(lambda fr: len(data_frames(fr[count:], 0)) >= 10)
        sequence = ["connected", "vid-pid", "device-string", "device-type"]
        assert services(line.frames()[count:], 0) == sequence
        count = len(line.frames())
        line.send(garbage[90:] + poll_present)  # asked again later: answered again
        line.wait_for(lambda fr: "device-type" in services(fr[count:], 0))
        assert services(line.frames()[count:], 0) == sequence
        line.wait_for(lambda fr: live_node(fr[count:]))
    finally:
        assert daemon.stop() == 0


def test_sighup_good_and_bad_config(tmp_path, line, replay_dir):
    config = tmp_path / "usb2rc.yaml"
    config.write_text(INVERT_UNGUARDED_X_CONFIG.format(invert="false"))
    install(replay_dir / "stick.hid", recording([StickState(), StickState(x=0)]))
    daemon = run_daemon(tmp_path, line.path, replay_dir, "--config", str(config))
    try:
        line.wait_for(lambda fr: live_node(fr, 4) and data_frames(fr, 4)[-1].axes[0] == -32768)
        count = len(line.frames())
        config.write_text(INVERT_UNGUARDED_X_CONFIG.format(invert="true"))
        daemon.signal(signal.SIGHUP)
        line.wait_for(
            lambda fr: (
                data_frames(fr[count:], 4)[-1:] and data_frames(fr[count:], 4)[-1].axes[0] == 32767
            )
        )
        config.write_text(INVERT_UNGUARDED_X_CONFIG.format(invert="maybe"))
        daemon.signal(signal.SIGHUP)
        count = len(line.frames())
        line.wait_for(lambda fr: len(data_frames(fr[count:], 4)) >= 25)
        assert {f.axes[0] for f in data_frames(line.frames()[count:], 4)} == {32767}
        codes = [f.code for f in data_frames(line.frames(), 4)]
        assert all(b == (a + 1) % 256 for a, b in itertools.pairwise(codes)), "a tick was lost"
    finally:
        assert daemon.stop() == 0
    log = daemon.log()
    assert "reloaded" in log
    assert "rejected" in log and f"{config}:7" in log
    assert "Traceback" not in log


def test_unusable_descriptor_reports_error_and_others_go_on(tmp_path, line, replay_dir):
    install(replay_dir / "a-good.hid", recording([StickState(), StickState(x=0)]))
    # a joystick collection that is never closed: the descriptor is unusable
    desc = "05 01 09 04 a1 01 75 08 95 01 15 00 26 ff 00 09 30 81 02"
    broken = f"R: 19 {desc}\nN: Broken Stick\nI: 3 1234 5678\nE: 0.0 1 00\n"
    install(replay_dir / "b-broken.hid", broken)
    daemon = run_daemon(tmp_path, line.path, replay_dir)
    try:
        line.wait_for(lambda fr: "error" in services(fr, 1))
        error = next(f for f in service_frames(line.frames(), 1))
        assert error.error_code == 0x02  # DESCRIPTOR_UNUSABLE
        line.wait_for(lambda fr: len(data_frames(fr, 0)) >= 10)
        assert not data_frames(line.frames(), 1)
    finally:
        assert daemon.stop() == 0
    assert "Broken Stick" in daemon.log()


SUMD_CONFIG = """
outputs:
  - protocol: c2-16b
  - protocol: sumd
    port: {sumd_port}
    channels: [node0.x, node0.y, node0.rz, node0.button1, node0.button16]
"""


def test_sumd_output_and_its_failsafe(tmp_path, line, replay_dir):
    sumd_line = PtyLine("sumd")
    config = tmp_path / "sumd.yaml"
    config.write_text(SUMD_CONFIG.format(sumd_port=sumd_line.path))
    state = StickState(x=0, y=16383, rz=0, buttons=0x0001)
    install(replay_dir / "stick.hid", recording([StickState(), state]))
    daemon = run_daemon(tmp_path, line.path, replay_dir, "--config", str(config))
    try:
        assert expected_frame(state)[0][6] == -32768
        # 1100 / 1900 µs × 8 (docs/ICD.md, "SUMD (HoTT) output")
        want = [8800, 15200, 8800, 15200, 8800]
        sumd_line.wait_for(lambda fr: any(f.channels == tuple(want) and not f.failsafe for f in fr))
        os.unlink(replay_dir / "stick.hid")
        sumd_line.wait_for(lambda fr: fr[-1].failsafe)
        last = sumd_line.frames()[-1]
        assert isinstance(last, sumd.SumdFrame)
        assert last.channels[:3] == tuple(want[:3])  # axes held
        assert last.channels[3:] == (8800, 8800)  # buttons released
    finally:
        assert daemon.stop() == 0
        sumd_line.close()


PINNED = """
devices:
  - name: stick
    match: {vid: 0x044f, pid: 0xb10a}
    node_id: 2
"""


def test_two_devices_on_one_config_entry_is_a_clash_not_a_merge(tmp_path, line, replay_dir):
    config = tmp_path / "pinned.yaml"
    config.write_text(PINNED)
    install(replay_dir / "a.hid", recording([StickState(), StickState(x=0)]))
    install(replay_dir / "b.hid", recording([StickState(), StickState(x=16383, buttons=1)]))
    daemon = run_daemon(tmp_path, line.path, replay_dir, "--config", str(config))
    try:
        line.wait_for(lambda fr: "error" in services(fr))
        line.wait_for(lambda fr: len([f for f in data_frames(fr, 2) if f.status == LIVE]) >= 10)
        error = next(f for f in service_frames(line.frames()) if f.service.service_name == "error")
        assert error.error_code == 0x05 and error.node_id != 2
        # node 2 is fed by the first device only (centred, then full left): never the other
        live = [f for f in data_frames(line.frames(), 2) if f.status == LIVE]
        assert {(f.axes[0], f.group1) for f in live} <= {(2, 0), (-32768, 0)}
    finally:
        assert daemon.stop() == 0
    assert "add `serial:` or `port:`" in daemon.log()
