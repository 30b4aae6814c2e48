"""The return path, black-box: the daemon as a subprocess on the real hidapi (umockdev), its
line a pty; what the far end (or the vehicle) says on the line reaches the fake device's
node as output reports, which the test reads on the node's other side (docs/ICD.md
"Downlink", docs/CONFIG.md "Feedback").

Expected bytes never come from usb2rc's drivers: the LED stick's report from hid-tools'
reading of its descriptor, the DualShock 4's from the kernel's documented layout
(drivers/hid/hid-playstation.c, `struct dualshock4_output_report_usb`)."""

from __future__ import annotations

import itertools
import json
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from daemon_harness import DaemonProcess, PtyLine, data_frames
from hid_encoder import encode, ref_reports
from pymavlink.dialects.v20 import common as mavlink2
from test_hid_outputs_umockdev import expected_report, input_report
from test_real_hidapi import daemon_prefix, wait_announced
from umockdev_harness import (
    LED_STICK_DESCRIPTOR,
    FakeStick,
    UsbBed,
    require_umockdev,
    serial_port_link,
    usb_bed,
    wait_until,
)

from usb2rc.protocols.c2_16b import codec as c2_16b
from usb2rc.protocols.crsf import codec as crsf

WAIT_S = 20.0
LIVE = c2_16b.LIVE
CENTRE = 2048  # the LED stick's X and Y rest (0..4095): the neutral guard lets it go live
REAL_DEVICES = json.loads((Path(__file__).parent / "data" / "real-devices.json").read_text())
DS4_DESCRIPTOR = bytes.fromhex(
    next(d["hex"] for d in REAL_DEVICES if (d["vid"], d["pid"]) == ("054c", "09cc"))
)


@pytest.fixture
def bed() -> Iterator[UsbBed]:
    require_umockdev()
    with usb_bed() as tb:
        yield tb


def led_stick(bed: UsbBed, port: str = "1-3") -> str:
    return bed.add(FakeStick(port, 0x1209, 0x0001, LED_STICK_DESCRIPTOR, "LED stick", "Test"))


class Written:
    """What the daemon wrote to a fake node, gathered as it comes (the node is a pty: the
    reports come glued; each of this node's reports has one length)."""

    def __init__(self, bed: UsbBed, hidraw: str, size: int) -> None:
        self.bed, self.hidraw, self.size = bed, hidraw, size
        self.data = bytearray()
        self.times: list[float] = []  # when each report was seen (the test's clock)

    def reports(self) -> list[bytes]:
        fresh = self.bed.written(self.hidraw)
        if fresh:
            before = len(self.data) // self.size
            self.data.extend(fresh)
            self.times += [time.monotonic()] * (len(self.data) // self.size - before)
        whole = len(self.data) // self.size * self.size
        return [bytes(self.data[i : i + self.size]) for i in range(0, whole, self.size)]

    def wait_for(self, report: bytes, what: str, timeout: float = WAIT_S) -> float:
        """Until `report` is the newest written; when it was seen."""
        reports = wait_until(lambda: (r := self.reports()) and r[-1] == report and r, timeout, what)
        return self.times[len(reports) - 1]


def downlink(node: int, code: int, group1: int = 0, group2: int = 0, axes: Any = None) -> bytes:
    return c2_16b.encode_data(LIVE, node, code, axes or [0] * 10, group1, group2)


def start(tmp_path: Path, bed: UsbBed, line: PtyLine, *args: str) -> DaemonProcess:
    port = serial_port_link(tmp_path, line.path)
    return DaemonProcess(
        ["--port", port, *args], tmp_path / "daemon.log", env=bed.env(), prefix=daemon_prefix()
    )


def with_config(
    tmp_path: Path, bed: UsbBed, line: PtyLine, output: str, rules: str
) -> DaemonProcess:
    """The daemon with one output (`output`: its protocol's keys) on `line`, and `rules`."""
    port = serial_port_link(tmp_path, line.path)
    config = tmp_path / "feedback.yaml"
    config.write_text(f"outputs:\n  - port: {port}\n{output}feedback:\n{rules}")
    return DaemonProcess(
        ["--config", str(config)], tmp_path / "daemon.log", env=bed.env(), prefix=daemon_prefix()
    )


LED_REPORT = len(expected_report(0, 255))
# The LED stick's input part alone: no output report (a device feedback leaves alone).
NO_OUTPUTS = bytes.fromhex(
    "05010904a101850109300931150026ff0f75109502810205091901290815002501750195088102c0"
)


def test_downlink_frames_light_the_indicators_and_a_silent_far_end_puts_them_to_rest(
    bed: UsbBed, line: PtyLine, tmp_path: Path
) -> None:
    """Zero config: node 0's downlink bits 0..7 are the LED stick's 8 indicators in
    descriptor order (5 LEDs, 2 ordinals, a vendor bit); its brightness axis at 0 leaves
    the LEDs at full. No downlink for 1 s: every indicator off."""
    node = led_stick(bed)
    written = Written(bed, node, LED_REPORT)
    daemon = start(tmp_path, bed, line)
    try:
        wait_announced(line, 0)
        for code, mask in enumerate((0b0000_0101, 0b1010_0010, 0b1111_1111, 0b1000_0000)):
            line.send(downlink(0, code, group1=mask))
            written.wait_for(expected_report(mask, 255), f"indicators {mask:#010b}")
        # bits above the device's 8 and group 2 light nothing on a node with one device
        line.send(downlink(0, 9, group1=0xFFFF_FF00, group2=0xFFFF_FFFF))
        written.wait_for(expected_report(0, 255), "bits beyond its indicators: none lit")
        line.send(downlink(0, 10, group1=0b11, axes=[0, 0, 0, 0, 16384, 0, 0, 0, 0, 0]))
        last_sent = time.monotonic()
        written.wait_for(expected_report(0b11, 128), "axis 5 sets the LED intensity")
        rest_seen = written.wait_for(expected_report(0, 255), "rest after a silent second")
        assert rest_seen - last_sent >= 1.0, "back to rest before the downlink was stale"
        assert "feedback drives 8 indicators" in daemon.log()
    finally:
        assert daemon.stop() == 0, daemon.log()[-3000:]
    # at stop the device is put to rest: nothing lit is left behind
    assert written.reports()[-1] == expected_report(0, 255)


def test_a_downlink_flood_costs_a_live_node_neither_its_rate_nor_its_frames(
    bed: UsbBed, line: PtyLine, tmp_path: Path
) -> None:
    """2,000 downlink frames a second for 3 s, while the stick is live: every frame the
    node sends meanwhile is `>` with the stick's values, the codes run on without a gap,
    and as many frames go out a second as before the flood. A stick without outputs on
    the same line is unaffected (nothing written to it)."""
    node = led_stick(bed)
    plain = bed.add(FakeStick("1-4", 0x1209, 0x0002, NO_OUTPUTS, "Plain", "Test"))
    daemon = start(tmp_path, bed, line)
    try:
        wait_announced(line, 0)
        wait_announced(line, 1)
        for hidraw in (node, plain):
            bed.report(hidraw, input_report(CENTRE))
        line.wait_for(lambda f: _live(f, 0, 1))
        before = _rate(line, 2.0)
        flood_started = time.monotonic()
        sent = _flood(line, rate_hz=2000, seconds=3.0)
        during = [s for s in line.seen_now() if s.time >= flood_started + 0.1]
        frames = [s.frame for s in during if isinstance(s.frame, c2_16b.DataFrame)]
        for node_id in (0, 1):
            own = [f for f in frames if f.node_id == node_id]
            assert own and all(f.status == LIVE for f in own), f"node {node_id} left `>`"
            assert len({(tuple(f.axes), f.group1, f.group2) for f in own}) == 1
            codes = [f.code for f in own]
            assert all((b - a) & 0xFF == 1 for a, b in itertools.pairwise(codes)), "a code gap"
        span = during[-1].time - during[0].time
        rate = len([f for f in frames if f.node_id == 0]) / span
        assert rate >= 0.8 * before, f"{rate:.1f} frames/s in the flood, {before:.1f} before"
        assert sent >= 5000
        assert bed.written(plain) == b""
    finally:
        assert daemon.stop() == 0, daemon.log()[-3000:]


def _live(frames: list[Any], *nodes: int) -> bool:
    return all((own := data_frames(frames, node)) and own[-1].status == LIVE for node in nodes)


def _rate(line: PtyLine, seconds: float) -> float:
    """Node 0's frames a second, over the next `seconds`."""
    start = time.monotonic()
    line.wait_for(lambda f: time.monotonic() - start >= seconds, timeout=seconds + WAIT_S)
    seen = [
        s
        for s in line.seen_now()
        if s.time >= start and isinstance(s.frame, c2_16b.DataFrame) and s.frame.node_id == 0
    ]
    return len(seen) / (seen[-1].time - seen[0].time)


def _flood(line: PtyLine, rate_hz: int, seconds: float) -> int:
    """Downlink frames for node 0 at `rate_hz`, 20 per write on absolute deadlines; how many
    went. A thread of its own: the test's own thread keeps reading the line."""
    sent = [0]
    batch = 20
    frames = b"".join(downlink(0, i & 0xFF, group1=i) for i in range(batch))

    def send() -> None:
        start = time.monotonic()
        step = batch / rate_hz
        n = 0
        while time.monotonic() - start < seconds:
            line.send(frames)
            sent[0] += batch
            n += 1
            time.sleep(max(0.0, start + n * step - time.monotonic()))

    thread = threading.Thread(target=send)
    thread.start()
    thread.join()
    return sent[0]


def test_crsf_link_quality_below_a_rule_rumbles_a_dualshock_4(bed: UsbBed, tmp_path: Path) -> None:
    """A CRSF module's link statistics with LQ 40 (< 50) on the CRSF line: the rule's rumble
    reaches the DualShock 4 (USB report 0x05: byte 5 the left, strong motor, byte 4 the
    right, weak one). LQ back at 100: the motors stop."""
    line = PtyLine("crsf")
    pad = bed.add(FakeStick("1-5", 0x054C, 0x09CC, DS4_DESCRIPTOR, "Wireless Controller", "Sony"))
    written = Written(bed, pad, 32)
    daemon = with_config(
        tmp_path,
        bed,
        line,
        "    protocol: crsf\n    channels: [node0.x, node0.y]\n",
        "  - when: crsf.link_quality < 50\n    rumble: {strong: 1.0, weak: 0.5}\n",
    )
    try:
        wait_until(lambda: "feedback drives" in daemon.log(), WAIT_S, "the pad driven")

        def stats(lq: int) -> bytes:
            return crsf.encode_link_statistics(
                crsf.LinkStatistics(60, 62, lq, 9, 0, 4, 3, 70, lq, 8)
            )

        def motors() -> tuple[int, int] | None:
            reports = written.reports()
            return (reports[-1][5], reports[-1][4]) if reports else None

        line.send(stats(40))
        wait_until(lambda: motors() == (255, 128), WAIT_S, "the rumble on LQ 40")
        report = written.reports()[-1]
        assert report[0] == 0x05 and len(report) == 32
        line.send(stats(100))
        wait_until(lambda: motors() == (0, 0), WAIT_S, "the rumble off on LQ 100")
    finally:
        code = daemon.stop()
        line.close_at_the_end()
        assert code == 0, daemon.log()[-3000:]


def test_a_vehicle_that_arms_lights_an_led(bed: UsbBed, tmp_path: Path) -> None:
    """A pymavlink vehicle stand-in on the MAVLink line: its HEARTBEAT with the armed flag
    lights the LED the rule names; disarmed, it goes out."""
    line = PtyLine("mavlink")
    node = led_stick(bed)
    written = Written(bed, node, LED_REPORT)
    daemon = with_config(
        tmp_path,
        bed,
        line,
        "    protocol: mavlink\n    channels: [node0.x, node0.y]\n",
        "  - when: mavlink.armed\n    led: LED Caps Lock\n",
    )
    vehicle = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)

    def heartbeat(armed: bool) -> bytes:
        flags = mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if armed:
            flags |= mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
        message = vehicle.heartbeat_encode(
            mavlink2.MAV_TYPE_QUADROTOR,
            mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA,
            flags,
            5,  # LOITER
            mavlink2.MAV_STATE_ACTIVE,
        )
        return bytes(message.pack(vehicle))

    try:
        wait_until(lambda: "feedback drives" in daemon.log(), WAIT_S, "the stick driven")
        line.send(heartbeat(armed=False))
        written.wait_for(expected_report(0, 255), "unlit while disarmed")
        line.send(heartbeat(armed=True))
        written.wait_for(expected_report(0b10, 255), "Caps Lock lit when armed")
        line.send(heartbeat(armed=False))
        written.wait_for(expected_report(0, 255), "unlit when disarmed again")
    finally:
        code = daemon.stop()
        line.close_at_the_end()
        assert code == 0, daemon.log()[-3000:]


def test_zero_config_a_node_entering_failsafe_pulses_its_gamepads_rumble_once(
    bed: UsbBed, line: PtyLine, tmp_path: Path
) -> None:
    """No config: a DualShock 4 plugged (its node in failsafe from the plug: no pulse), live
    on centred reports streamed every 25 ms, then silent: its node enters failsafe (`3`
    0x07, docs/ICD.md "A device that falls silent") and the pad's motors run at full for
    the pulse, then stop; once."""
    pad = bed.add(FakeStick("1-5", 0x054C, 0x09CC, DS4_DESCRIPTOR, "Wireless Controller", "Sony"))
    written = Written(bed, pad, 32)
    (ref,) = ref_reports(DS4_DESCRIPTOR).values()
    centred = encode(
        ref,
        {
            (0x10030, 0): 128,
            (0x10031, 0): 128,
            (0x10032, 0): 128,
            (0x10035, 0): 128,
            (0x10039, 0): 8,
        },
    )
    daemon = start(tmp_path, bed, line)
    try:
        wait_announced(line, 0)
        start_at = time.monotonic()
        for i in range(40):  # streaming: learned after 20 reports the same as the one before
            time.sleep(max(0.0, start_at + i * 0.025 - time.monotonic()))
            bed.report(pad, centred)
        line.wait_for(lambda f: (own := data_frames(f, 0)) and own[-1].status == LIVE)
        assert all(r[4:6] == b"\x00\x00" for r in written.reports()), "a pulse at the plug"
        # silent from here: the node fails safe, the pad pulses
        wait_until(
            lambda: any(r[4:6] == b"\xff\xff" for r in written.reports()), WAIT_S, "the pulse"
        )
        wait_until(lambda: written.reports()[-1][4:6] == b"\x00\x00", WAIT_S, "the pulse's end")
        motors = [r[4:6] for r in written.reports()]
        runs = sum(
            1 for a, b in itertools.pairwise(motors) if a != b"\xff\xff" and b == b"\xff\xff"
        )
        assert runs == 1, motors
        assert "silent" in daemon.log()
    finally:
        assert daemon.stop() == 0, daemon.log()[-3000:]


def test_a_reload_changes_what_the_rules_light_and_a_replugged_device_shows_it_again(
    bed: UsbBed, line: PtyLine, tmp_path: Path
) -> None:
    """Feedback meets a reload and a replug: a rule with no `when` lights Num Lock; the
    config rewritten to light Caps Lock and reloaded (SIGHUP), the device shows Caps Lock
    alone; unplugged and plugged again (a new hidraw node), the new node is written the
    same state, with no downlink or rule change needed."""
    node = led_stick(bed)
    written = Written(bed, node, LED_REPORT)
    daemon = with_config(tmp_path, bed, line, "    protocol: c2-16b\n", "  - led: LED Num Lock\n")
    try:
        written.wait_for(expected_report(0b01, 255), "Num Lock lit by the rule")
        config = tmp_path / "feedback.yaml"
        config.write_text(config.read_text().replace("LED Num Lock", "LED Caps Lock"))
        daemon.signal(signal.SIGHUP)
        written.wait_for(expected_report(0b10, 255), "Caps Lock alone after the reload")
        bed.remove(node)
        wait_announced(line, 0)  # (the first announcement; the replug's is awaited below)
        again = led_stick(bed)
        assert again != node
        wait_announced(line, 0, times=2)
        Written(bed, again, LED_REPORT).wait_for(
            expected_report(0b10, 255), "the replugged device shows the rule's state"
        )
    finally:
        assert daemon.stop() == 0, daemon.log()[-3000:]
