"""`usb2rc describe` as a subprocess: hex and hid-recorder input, JSON, errors."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from usb2rc.hid.recording import RecordedEvent, Recording, format_recording

DEVICES = {
    d["name"]: d
    for d in json.loads((Path(__file__).parent / "data" / "real-devices.json").read_text())
}
T16000M = DEVICES["Thrustmaster T.16000M"]["hex"]


def usb2rc(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "usb2rc", "describe", *args],
        capture_output=True,
        text=True,
        timeout=60,
    )


def test_hex_text_lists_fields_and_default_mapping() -> None:
    result = usb2rc("--hex", T16000M)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[0] == "application: Joystick (device type JOYSTICK)"
    assert "  1   0   X                  24+14               0..16383             no" in lines
    assert "  hat HatSwitch -> hat1 (group 1 bits 24-31)" in lines
    assert any(line.startswith("  axis rz     <- Rz (raw 0..255") for line in lines)


def test_json_and_recorded_reports(tmp_path: Path) -> None:
    # T.16000M report: buttons (16 bits), hat nibble + pad, X 14 bits + pad, Y, Rz, Slider
    report = bytes([0x05, 0x00, 0x02, 0xFF, 0x3F, 0x00, 0x00, 0x80, 0x10]) + bytes(55)
    rec = Recording(
        bytes.fromhex(T16000M), "T.16000M", "", 3, 0x044F, 0xB10A, (RecordedEvent(0.5, report),)
    )
    path = tmp_path / "stick.hid"
    path.write_text(format_recording(rec))
    result = usb2rc(str(path), "--json", "--reports", "1")
    assert result.returncode == 0, result.stderr
    info = json.loads(result.stdout)
    assert [f["usage"] for f in info["inputs"]] == ["HatSwitch", "X", "Y", "Rz", "Slider"]
    assert info["button_count"] == 16
    (decoded,) = info["reports"]
    assert decoded["buttons"] == [1, 3]
    assert decoded["values"] == {"HatSwitch": 2, "X": 16383, "Y": 0, "Rz": 128, "Slider": 16}


def test_errors_exit_2() -> None:
    assert usb2rc("--hex", "zz").returncode == 2
    assert usb2rc().returncode == 2
    result = usb2rc("/no/such/file.hid")
    assert result.returncode == 2
    assert "file.hid" in result.stderr
