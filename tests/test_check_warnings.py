"""`usb2rc check` warns about what the SUMD decoders of PX4, ArduPilot and Betaflight would
not take, and about SUMD channels on unpinned nodes: exit 0, warnings on stderr
(docs/CONFIG.md, "SUMD receivers")."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from usb2rc.commands.check import warnings
from usb2rc.configfile import load_config_text
from usb2rc.nodes.mapping import compile_mapping

STICK = """
devices:
  - name: stick
    match: {vid: 0x044f}
    node_id: 1
"""
CHANNELS = [f"node1.{slot}" for slot in ("x", "y", "z", "rx", "ry", "rz", "slider", "dial")]
CHANNELS += [f"node1.button{n}" for n in range(1, 25)]


def sumd_config(count: int | None, baudrate: int = 115200, devices: str = STICK) -> str:
    channels = "" if count is None else f"\n    channels: [{', '.join(CHANNELS[:count])}]"
    return (
        f"outputs:\n  - protocol: sumd\n    port: /dev/ttyUSB9\n    baudrate: {baudrate}"
        f"{channels}\n{devices}"
    )


def warned(text: str) -> list[str]:
    config = load_config_text(text, "sumd.yaml")
    return [str(problem) for problem in warnings(config, compile_mapping(config))]


@pytest.mark.parametrize(("count", "warns"), [(2, True), (3, True), (4, False), (8, False)])
def test_fewer_than_4_channels_px4_and_ardupilot(count, warns):
    found = [w for w in warned(sumd_config(count)) if "fewer than 4" in w]
    assert bool(found) == warns
    if warns:
        assert found[0].startswith("sumd.yaml:2: outputs[0].channels: warning:")
        assert "PX4 and ArduPilot" in found[0]


@pytest.mark.parametrize(("count", "warns"), [(18, False), (19, True), (20, True)])
def test_more_than_18_channels_px4_and_betaflight(count, warns):
    found = [w for w in warned(sumd_config(count)) if "first 18" in w]
    assert bool(found) == warns
    if warns:
        assert "PX4 and Betaflight" in found[0]
        dropped = found[0].split("they drop ")[1].split()
        assert dropped == CHANNELS[18:count]


@pytest.mark.parametrize(
    ("count", "baudrate", "warns"),
    [(26, 115200, False), (27, 115200, True), (32, 115200, True), (32, 230400, False)],
)
def test_a_frame_longer_than_5_ms_ardupilot(count, baudrate, warns):
    found = [w for w in warned(sumd_config(count, baudrate)) if "ArduPilot drops" in w]
    assert bool(found) == warns
    if warns:
        assert f"at {baudrate} baud" in found[0]
        assert "at most 26 channels" in found[0]


def test_channels_on_a_node_no_entry_pins():
    text = sumd_config(None, devices="").replace(
        "port: /dev/ttyUSB9",
        "port: /dev/ttyUSB9\n    channels: [node1.x, node3.y, node1.z, node1.rx]",
    )
    found = [w for w in warned(text + STICK) if "pins node" in w]
    assert found == [
        "sumd.yaml:4: outputs[0].channels[1]: warning: node3.y: no device entry pins node 3; "
        "the channel reads whichever device is numbered 3 automatically (plug order). "
        "Pin one with `node_id: 3`"
    ]


def test_the_default_channel_list_of_an_unpinned_node_warns_once():
    assert [w for w in warned(sumd_config(None, devices="")) if "pins node 0" in w] == [
        "sumd.yaml:2: outputs[0]: warning: the default channels: no device entry pins node 0; "
        "the channel reads whichever device is numbered 0 automatically (plug order). "
        "Pin one with `node_id: 0`"
    ]
    assert warned(sumd_config(None)) == []  # node 1 pinned: its 8 default channels


def test_check_exits_0_and_prints_the_warnings_on_stderr(tmp_path: Path):
    path = tmp_path / "sumd.yaml"
    path.write_text(sumd_config(27).replace("node1.x", "node2.x"))
    result = subprocess.run(
        [sys.executable, "-m", "usb2rc", "check", "--config", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.endswith(f"\n{path}: OK\n")  # the verdict comes last
    lines = result.stderr.splitlines()
    assert len(lines) == 3 and all(": warning: " in line for line in lines)
    assert ["Betaflight" in lines[0], "ArduPilot" in lines[1], "node2.x" in lines[2]] == [True] * 3


def test_c2_16b_outputs_get_no_sumd_warnings():
    assert warned("outputs:\n  - protocol: c2-16b\n    port: /dev/ttyUSB9\n") == []
