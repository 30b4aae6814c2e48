"""CRSF straight into a flight controller (issue 20 point 2): `address: flight_controller`.

Betaflight's CRSF receiver takes an RC frame only when its first byte is 0xC8, the address a
receiver uses towards a flight controller; PX4 takes any address. `FcCrsfReader` below is a
decoder written for these tests from the CRSF description alone (docs/ICD.md, "CRSF output";
the TBS CRSF description): a frame is

    sync/address, length n (2..62: type + payload + CRC), type, n - 2 payload bytes,
    CRC-8/DVB-S2 (polynomial 0xD5, init 0, MSB first) over type and payload

and an RC_CHANNELS_PACKED frame (type 0x16) carries 22 bytes: 16 channels of 11 bits, LSB
first. With `betaflight=True` it keeps only frames whose first byte is 0xC8, as Betaflight's
parser does; with False it keeps any address, as PX4's does. It shares no code with usb2rc
(nor with tests/rc_reference.py, which reads frames to a module).
"""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from daemon_harness import PtyLine, StickState, expected_frame, install, recording, run_daemon

from usb2rc.commands.check import describe_output, warnings
from usb2rc.configfile import ConfigError, load_config_text
from usb2rc.nodes.mapping import compile_mapping

WAIT_S = 20.0
SYNC_FC = 0xC8
RC_CHANNELS_PACKED = 0x16
STICK = [StickState(), StickState(x=3000, y=12000, buttons=1)]
CHANNELS = ["node0.x", "node0.y", "node0.button1"]


def crc8_dvb_s2(data: bytes) -> int:
    """Bit by bit, from the polynomial: x^8 + x^7 + x^6 + x^4 + x^2 + 1."""
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0xD5) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc


def unpack11(block: bytes) -> list[int]:
    """16 channels of 11 bits, LSB first, as one little-endian integer of 176 bits."""
    bits = int.from_bytes(block[:22], "little")
    return [(bits >> (11 * n)) & 0x7FF for n in range(16)]


@dataclass
class FcFrame:
    address: int
    type: int
    payload: bytes


@dataclass
class FcCrsfReader:
    """A flight controller's CRSF parser: Betaflight's rules or PX4's (see the module)."""

    betaflight: bool = True
    buffer: bytearray = field(default_factory=bytearray)
    skipped: int = 0  # bytes in no frame it takes
    crc_failures: int = 0

    def feed(self, data: bytes) -> list[FcFrame]:
        self.buffer += data
        frames = []
        while len(self.buffer) >= 2:
            address, length = self.buffer[0], self.buffer[1]
            if (self.betaflight and address != SYNC_FC) or not 2 <= length <= 62:
                self._skip()
                continue
            if len(self.buffer) < length + 2:
                break
            body = bytes(self.buffer[2 : length + 1])
            if crc8_dvb_s2(body) != self.buffer[length + 1]:
                self.crc_failures += 1
                self._skip()
                continue
            frames.append(FcFrame(address, body[0], body[1:]))
            del self.buffer[: length + 2]
        return frames

    def _skip(self) -> None:
        del self.buffer[0]
        self.skipped += 1


def rc_channels(frames: list[FcFrame]) -> list[list[int]]:
    return [
        unpack11(f.payload) for f in frames if f.type == RC_CHANNELS_PACKED and len(f.payload) == 22
    ]


def test_the_reference_decoder_matches_the_published_crc_check_value():
    assert crc8_dvb_s2(b"123456789") == 0xBC  # CRC-8/DVB-S2's catalogue check value


class FlightControllerUart(PtyLine):
    """A flight controller's receiver UART: what the daemon writes, read by Betaflight's rules
    (the line's decoder) and by PX4's (`px4`), every byte."""

    def __init__(self) -> None:
        super().__init__("crsf")
        self.decoder = FcCrsfReader(betaflight=True)
        self.px4 = FcCrsfReader(betaflight=False)
        self.px4_frames: list[FcFrame] = []

    def _received(self, now: float, data: bytes, frames: list[object]) -> None:
        super()._received(now, data, frames)
        self.px4_frames += self.px4.feed(data)


def rc11(value: int) -> int:
    """docs/ICD.md, "CRSF and SBUS channel values": 172 + round((v + 32768) * 1639 / 65535)."""
    return 172 + (2 * (value + 32768) * 1639 + 65535) // (2 * 65535)


def test_a_flight_controller_takes_every_frame_of_a_crsf_output_to_it(tmp_path: Path, replay_dir):
    fc = FlightControllerUart()
    install(replay_dir / "a.hid", recording(STICK))
    path = tmp_path / "fc.yaml"
    path.write_text(
        "outputs:\n"
        f"  - protocol: crsf\n    port: {fc.path}\n    address: flight_controller\n"
        f"    baudrate: 420000\n    channels: [{', '.join(CHANNELS)}]\n"
        "devices:\n  - {name: a, match: {port: replay-a}, node_id: 0}\n"
    )
    axes, group1, _ = expected_frame(STICK[-1])
    wanted = [rc11(axes[0]), rc11(axes[1]), 1811 if group1 & 1 else 172] + [172] * 13
    daemon = run_daemon(tmp_path, fc.path, replay_dir, "--config", str(path))
    try:
        fc.wait_for(lambda frames: len(rc_channels(frames)) >= 50, WAIT_S)
        fc.wait_for(lambda frames: rc_channels(frames)[-1] == wanted, WAIT_S)
    finally:
        code = daemon.stop()
        assert code == 0, daemon.log()[-3000:]
        fc.close()
    taken = fc.frames()
    # frame for frame: every byte written is in a frame Betaflight takes, and PX4 the same
    assert fc.decoder.skipped == 0 and fc.decoder.crc_failures == 0
    assert all(f.address == SYNC_FC and f.type == RC_CHANNELS_PACKED for f in taken)
    assert fc.px4_frames == taken and fc.px4.skipped == 0


def load(text: str) -> object:
    return load_config_text(f"outputs:\n  - protocol: crsf\n    port: /dev/null\n{text}", "c.yaml")


@pytest.mark.parametrize(
    ("given", "address"),
    [("", 0xEE), ("module", 0xEE), ("flight_controller", 0xC8), ("0xEA", 0xEA), ("0", 0)],
)
def test_the_address_key_takes_a_name_or_a_byte(given: str, address: int):
    text = f"    address: {given}\n" if given else ""
    config = load(text + "    channels: [node0.x]\n")
    (output,) = config.outputs  # type: ignore[attr-defined]
    assert output.option("address") == address
    assert f"to 0x{address:02X}" in describe_output(output)


@pytest.mark.parametrize(
    ("given", "says"),
    [
        ("fc", "'fc' is not valid (allowed: module, flight_controller, an integer 0..255)"),
        ("256", "256 is out of range (allowed: 0..255)"),
        ("true", "expected an integer, got 'true' (allowed: 0..255)"),
    ],
)
def test_a_bad_address_names_the_file_line_and_key(given: str, says: str):
    with pytest.raises(ConfigError) as caught:
        load(f"    channels: [node0.x]\n    address: {given}\n")
    assert f"c.yaml:5: outputs[0].address: {says}" in str(caught.value)


def warned(text: str) -> list[str]:
    config = load(text + "    channels: [node0.x]\n")
    return [str(problem) for problem in warnings(config, compile_mapping(config))]  # type: ignore[arg-type]


def test_check_warns_when_a_flight_controller_is_not_sent_420000_baud():
    (warning,) = warned("    address: flight_controller\n")
    assert warning.startswith("c.yaml:2: outputs[0]: warning: address flight_controller at")
    assert "set `baudrate: 420000`" in warning
    assert warned("    address: flight_controller\n    baudrate: 420000\n") == []
    assert warned("    address: module\n") == []


def test_check_warns_about_an_address_neither_a_module_nor_a_flight_controller():
    (warning,) = warned("    address: 0xEA\n")
    assert "address 0xEA: Betaflight takes RC frames only to 0xC8" in warning


def test_usb2rc_check_prints_the_warning_and_exits_0(tmp_path: Path):
    path = tmp_path / "fc.yaml"
    path.write_text(
        "outputs:\n  - protocol: crsf\n    port: /dev/ttyUSB0\n    address: flight_controller\n"
        "    channels: [node0.x]\n"
    )
    done = subprocess.run(
        [sys.executable, "-m", "usb2rc", "check", "--config", str(path)],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr
    assert "warning: address flight_controller at 400000 baud" in done.stderr
