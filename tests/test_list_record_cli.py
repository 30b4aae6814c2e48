"""`usb2rc list` and `usb2rc record` over replayed devices (and a fake backend for errors)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from test_replay import JOYSTICK, numbered, recording_text

from usb2rc.cli import main
from usb2rc.commands import list_devices
from usb2rc.hid.backend import DeviceInfo, DevicePermissionError
from usb2rc.hid.permissions import permission_message
from usb2rc.hid.recording import parse_recording
from usb2rc.hid.replay import ReplayBackend, install_file

DEMO = Path(__file__).resolve().parent.parent / "usb2rc" / "data" / "demo"
DEMO_STICK = parse_recording((DEMO / "stick.hid").read_text().splitlines()).descriptor


def list_json_subprocess(directory: Path) -> dict:
    out = subprocess.run(
        [sys.executable, "-m", "usb2rc", "list", "--replay", str(directory), "--json"],
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    return json.loads(out.stdout)


def test_list_json_sees_plug_and_unplug(tmp_path: Path) -> None:
    assert list_json_subprocess(tmp_path)["devices"] == []
    install_file(tmp_path / "b.hid", recording_text(numbered(1), descriptor=DEMO_STICK))
    install_file(tmp_path / "a.hid", recording_text(numbered(1), descriptor=DEMO_STICK))
    listed = list_json_subprocess(tmp_path)
    assert listed["backend"] == "replay"
    devices = listed["devices"]
    assert [(d["serial"], d["port_path"], d["node_id"]) for d in devices] == [
        ("a", "replay-a", 0),
        ("b", "replay-b", 1),
    ]
    assert devices[0]["vid"] == "044f" and devices[0]["usage_name"] == "Joystick"
    assert devices[0]["used"] is True and devices[0]["problem"] is None
    (tmp_path / "a.hid").unlink()
    assert [d["serial"] for d in list_json_subprocess(tmp_path)["devices"]] == ["b"]


def test_list_text_and_problems(tmp_path: Path, capsys) -> None:
    install_file(tmp_path / "stick.hid", recording_text(numbered(1), descriptor=DEMO_STICK))
    install_file(tmp_path / "nodesc.hid", recording_text(numbered(1), descriptor=JOYSTICK))
    install_file(tmp_path / "junk.txt", "hello\n")
    assert main(["list", "--replay", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "044f:b10a  Test Stick  [node 0]" in out
    assert "port replay-stick" in out
    assert "why not: report descriptor unusable" in out  # nodesc: no input fields
    assert "problem:" in out and "junk.txt" in out


def test_list_empty_hints(tmp_path: Path, capsys) -> None:
    assert main(["list", "--replay", str(tmp_path)]) == 0
    assert "No devices" in capsys.readouterr().out


def test_list_all_includes_non_joysticks(tmp_path: Path, capsys) -> None:
    mouse = bytes.fromhex("05010902a101c0")
    install_file(tmp_path / "mouse.hid", recording_text([], descriptor=mouse))
    assert main(["list", "--replay", str(tmp_path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["devices"] == []
    assert main(["list", "--replay", str(tmp_path), "--json", "--all"]) == 0
    [row] = json.loads(capsys.readouterr().out)["devices"]
    assert (row["usage_name"], row["used"]) == ("Mouse", False)
    assert "not a joystick" in row["problem"]


class LockedBackend:
    """A hidraw device this user may not open."""

    name = "fake"

    def enumerate(self, all: bool = False) -> list[DeviceInfo]:
        return [
            DeviceInfo(
                "/dev/hidraw3",
                "/dev/hidraw3",
                0x044F,
                0xB10A,
                "S",
                "",
                "Stick",
                0,
                "1-1.2",
                1,
                4,
                "/dev/hidraw3",
            )
        ]

    def open(self, info: DeviceInfo):
        raise DevicePermissionError(13, permission_message(info.hidraw))


def test_list_names_the_udev_rule_on_permission_denied(monkeypatch, capsys) -> None:
    monkeypatch.setattr(list_devices, "make_backend", lambda replay: LockedBackend())
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    assert "not used" in out and "/dev/hidraw3" in out
    assert "usb2rc install-system" in out and "udevadm" in out
    assert "systemd/" not in out  # no path in a source tree


def test_list_takes_pins_from_config(tmp_path: Path, capsys) -> None:
    pytest.importorskip("usb2rc.nodes.mapping")
    for stem in ("a", "b", "c"):
        install_file(tmp_path / f"{stem}.hid", recording_text([], descriptor=DEMO_STICK))
    config = tmp_path / "cfg" / "usb2rc.yaml"
    config.parent.mkdir()
    config.write_text(
        "outputs:\n  - protocol: c2-16b\n"
        "devices:\n  - name: pinned\n    match: {serial: c}\n    node_id: 0\n"
    )
    assert main(["list", "--replay", str(tmp_path), "--json", "--config", str(config)]) == 0
    rows = json.loads(capsys.readouterr().out)["devices"]
    assert [(r["serial"], r["node_id"]) for r in rows] == [("a", 1), ("b", 2), ("c", 0)]


def test_record_rerecords_a_replay(tmp_path: Path, capsys) -> None:
    events = numbered(40, step=0.001)
    install_file(tmp_path / "src.hid", recording_text(events, descriptor=DEMO_STICK))
    assert main(["record", "--replay", str(tmp_path), "src", "--seconds", "1.0"]) == 0
    out = capsys.readouterr().out
    rec = parse_recording(out.splitlines())
    assert rec.descriptor == DEMO_STICK
    assert (rec.vid, rec.pid, rec.name) == (0x044F, 0xB10A, "Test Stick")
    assert [e.report for e in rec.events] == [r for _, r in events]
    times = [e.time_s for e in rec.events]
    assert times == sorted(times)


def test_record_by_vid_pid(tmp_path: Path, capsys) -> None:
    install_file(tmp_path / "s.hid", recording_text(numbered(2), descriptor=DEMO_STICK))
    assert main(["record", "--replay", str(tmp_path), "044f:b10a", "--seconds", "0.2"]) == 0
    assert len(parse_recording(capsys.readouterr().out.splitlines()).events) == 2


def test_record_unknown_device(tmp_path: Path, capsys) -> None:
    assert main(["record", "--replay", str(tmp_path), "nothing", "--seconds", "0.1"]) == 1
    assert "no device matches" in capsys.readouterr().err


def test_record_read_failure_exits_1(tmp_path: Path, capsys) -> None:
    text = recording_text(numbered(1), descriptor=DEMO_STICK, fault_at=0.01)
    install_file(tmp_path / "f.hid", text)
    assert main(["record", "--replay", str(tmp_path), "f", "--seconds", "5"]) == 1
    assert "read failed" in capsys.readouterr().err


def test_backend_directory_is_demo_ready() -> None:
    assert len(ReplayBackend(DEMO).enumerate()) == 2
