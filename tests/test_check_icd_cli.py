"""`usb2rc check` and `usb2rc icd` as subprocesses: exit codes and exact file:line errors."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from usb2rc.hid.recording import Recording, format_recording

DATA = Path(__file__).parent / "data"
CONFIGS = DATA / "configs"
REPO = Path(__file__).parent.parent
BROKEN = sorted((CONFIGS / "broken").glob("*.yaml"))
STARTERS = REPO / "usb2rc" / "data" / "config"  # the starter configs the package ships
GOOD = sorted((CONFIGS / "good").glob("*.yaml")) + sorted(STARTERS.glob("*.yaml"))


def usb2rc(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "usb2rc", *args], capture_output=True, text=True, timeout=60
    )


def expectations(path: Path) -> list[str]:
    """`# expect: LINE: text` comments: each error must start with `path:LINE: text`."""
    found = re.findall(r"^# expect: (\d+): (.*)$", path.read_text(), re.MULTILINE)
    return [f"{path}:{line}: {text}" for line, text in found]


@pytest.mark.parametrize("path", BROKEN, ids=lambda p: p.stem)
def test_broken_config_exits_2_with_every_error_and_line(path: Path) -> None:
    result = usb2rc("check", "--config", str(path))
    assert result.returncode == 2, result.stdout
    errors = result.stderr.splitlines()[:-1]
    expected = expectations(path)
    assert expected, "the test file must say what it expects"
    assert len(errors) == len(expected), result.stderr
    for want, got in zip(expected, errors, strict=True):
        assert got.startswith(want), f"{got!r} does not start with {want!r}"
    assert result.stderr.splitlines()[-1] == f"{len(expected)} error(s)"


@pytest.mark.parametrize("path", GOOD, ids=lambda p: p.stem)
def test_good_config_exits_0_with_summary(path: Path) -> None:
    # default.yaml leaves the port to `run --port`: check is told the same
    port = ["--port", "/dev/ttyUSB0"] if path.name == "default.yaml" else []
    result = usb2rc("check", "--config", str(path), *port)
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("outputs:\n")
    assert result.stdout.endswith(f"\n{path}: OK\n")  # the verdict comes last


def test_missing_file_exits_2() -> None:
    result = usb2rc("check", "--config", str(CONFIGS / "no-such-file.yaml"))
    assert result.returncode == 2
    assert "no-such-file.yaml: cannot read" in result.stderr


def test_summary_lists_nodes_and_channels() -> None:
    result = usb2rc("check", "--config", str(STARTERS / "hotas.yaml"))
    lines = result.stdout.splitlines()
    assert "  node 2: pedals: axes rz x y" in lines
    assert any(
        line.strip().startswith("8 channels: node1.x node1.y node1.z node2.rz") for line in lines
    )
    assert "  devices without an entry: ignored (defaults: false)" in lines


def write_replay(directory: Path, names: list[str]) -> None:
    devices = {d["name"]: d for d in json.loads((DATA / "real-devices.json").read_text())}
    for i, name in enumerate(names):
        d = devices[name]
        rec = Recording(
            bytes.fromhex(d["hex"]), name[:30], "", 3, int(d["vid"], 16), int(d["pid"], 16)
        )
        (directory / f"dev{i}.hid").write_text(format_recording(rec))


def test_check_replay_binds_devices_and_reports_missing_usage(tmp_path: Path) -> None:
    write_replay(
        tmp_path,
        ["Thrustmaster T.16000M", "Thrustmaster TWCS Throttle", "Logitech WingMan Force 3D"],
    )
    config = tmp_path / "c.yaml"
    config.write_text(
        "devices:\n"
        "  - name: stick\n"
        "    match: {vid: 0x044f, pid: 0xb10a}\n"
        "    node_id: 1\n"
        "    axes: {x: X, z: Z}\n"
        "  - name: throttle\n"
        "    match: {vid: 0x044f, pid: 0xb687}\n"
        "    node_id: 2\n"
        "    axes: {z: Z}\n"
    )
    result = usb2rc(
        "check", "--config", str(config), "--replay", str(tmp_path), "--port", "loop://"
    )
    assert result.returncode == 2
    out = result.stdout
    assert f"ERROR {config}:5: devices[0].axes.z: usage Z is not in this device" in out
    assert "(044f:b687): node 2 as 'throttle'" in out
    assert "(046d:c283): node 0 as" in out  # automatic: lowest free ID


def test_icd_markdown_names_sources_and_sumd_ranges() -> None:
    result = usb2rc("icd", "--config", str(STARTERS / "hotas.yaml"), "--format", "markdown")
    assert result.returncode == 0, result.stderr
    out = result.stdout
    assert "## Node 1" in out and "## Node 2" in out
    assert "| z | throttle | Z | signed | -32768..32767 | -32768 |" in out
    assert "| x | pedals | X | unsigned | 0..65535 | 0 |" in out
    assert "| 25 | 2 | 0 | throttle | HID button 1 |" in out
    assert "| 8 | node1.button25 | button | 1100 / 1900 |" in out
    assert "| 1 | node1.x | axis, signed | 1100..1900 |" in out


def test_icd_zero_config_describes_default_layout() -> None:
    result = usb2rc("icd")
    assert result.returncode == 0, result.stderr
    assert "HID buttons 1-24" in result.stdout
    assert "group 1 bits 24-31" in result.stdout


def test_icd_bad_config_exits_2() -> None:
    result = usb2rc("icd", "--config", str(CONFIGS / "broken" / "axis-clash.yaml"))
    assert result.returncode == 2
    assert "axis-clash.yaml:10:" in result.stderr


def test_icd_says_when_a_node_sends_handover_and_low_battery(tmp_path: Path) -> None:
    config = tmp_path / "status.yaml"
    config.write_text(
        "devices:\n  - name: stick\n    match: {vid: 0x044f}\n    node_id: 2\n"
        "    handover: {button: 5, destination: 7, frames: 10}\n"
        "    low_battery: {usage: Slider, below: 10}\n"
    )
    result = usb2rc("icd", "--config", str(config), "--format", "text")
    assert result.returncode == 0, result.stderr
    assert (
        "Status `&` (byte 4 = destination 7): HID button 5 of stick, 10 frames a press; "
        "no message code is used." in result.stdout
    )
    assert "Status `%`: Slider of stick below 10 %." in result.stdout
