"""`usb2rc check` warns about what the SUMD decoders of PX4, ArduPilot and Betaflight would
not take, and about SUMD channels on unpinned nodes: exit 0, warnings on stderr
(docs/CONFIG.md, "SUMD receivers")."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from usb2rc.commands.check import warnings
from usb2rc.config.unfed import DeviceFeed, unfed_slot_warnings
from usb2rc.config.yamlnodes import Where
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


# --- channels that read an axis slot no device of their node feeds (issue 39, point 7) -----

ROOT = Path(__file__).resolve().parent.parent
STICK_RECORDING = ROOT / "usb2rc" / "data" / "demo" / "stick.hid"  # a T.16000M: no Z
USB2RC = [sys.executable, "-m", "usb2rc"]
T16000M_HAS = "Thrustmaster T.16000M (044f:b10a) has axes x, y, slider, rz"


def check_replay(tmp_path: Path, config_text: str, *extra: str) -> subprocess.CompletedProcess:
    """`usb2rc check --config FILE --replay DIR` with DIR holding only the T.16000M."""
    replay = tmp_path / "stick"
    replay.mkdir(exist_ok=True)
    (replay / "stick.hid").write_text(STICK_RECORDING.read_text())
    config = tmp_path / "crsf.yaml"
    config.write_text(config_text)
    return subprocess.run(
        [*USB2RC, "check", "--config", config.name, "--replay", replay.name, *extra],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=tmp_path,
    )


CRSF_ON_T16000M = (
    "outputs:\n  - protocol: crsf\n    port: /dev/ttyUSB9\n"
    "    channels: [node0.x, node0.y, node0.z, node0.rz]\n"
)


def test_a_channel_reading_a_slot_the_replayed_device_lacks_is_warned(tmp_path: Path):
    result = check_replay(tmp_path, CRSF_ON_T16000M)
    assert result.returncode == 0, result.stderr  # a warning: the config is still good
    assert result.stdout.endswith("crsf.yaml: OK\n")
    unfed = [line for line in result.stderr.splitlines() if "no device of node 0" in line]
    assert unfed == [
        "crsf.yaml:4: outputs[0].channels[2]: warning: node0.z reads axis z of node 0, which "
        f"no device of node 0 feeds: {T16000M_HAS}. Channel 3 never moves (it sends the "
        "slot's 0, the centre)"
    ]  # before: OK and no warning, while channel 3 sent a constant centre
    document = json.loads(check_replay(tmp_path, CRSF_ON_T16000M, "--json").stdout)
    (record,) = [p for p in document["problems"] if "no device of node 0" in p["message"]]
    assert (record["line"], record["key"], record["severity"]) == (
        4,
        "outputs[0].channels[2]",
        "warning",
    )


def test_mix_inputs_and_default_lists_are_warned_and_fed_slots_are_not(tmp_path: Path):
    mixed = (
        "outputs:\n  - protocol: sumd\n    port: /dev/ttyUSB9\n"
        "    channels: [node0.x, node0.y, node0.rz, {mix: [{source: node0.ry}, "
        "{source: node0.slider}]}, node0.aux1]\n"
        "switches:\n  gear: {toggle: node0.button1, slot: aux1}\n"
    )
    lines = check_replay(tmp_path, mixed).stderr.splitlines()
    unfed = [line for line in lines if "no device of node 0" in line]
    assert len(unfed) == 1 and "node0.ry (in the mix of channel 4)" in unfed[0]
    assert "Its part of the mix never moves" in unfed[0]  # aux1 is the switch's: fed
    default = "outputs:\n  - protocol: sumd\n    port: /dev/ttyUSB9\n"
    lines = check_replay(tmp_path, default).stderr.splitlines()
    unfed = [line for line in lines if "no device of node 0" in line]
    assert unfed == [
        "crsf.yaml:2: outputs[0].channels: warning: the default channels node0.z, node0.rx, "
        "node0.ry, node0.dial (channels 3, 6, 7, 8) read axes no device of node 0 feeds: "
        f"{T16000M_HAS}. They never move (they send the slot's 0, the centre): list the "
        "channels you want with `channels:`"
    ]
    c2 = "outputs:\n  - protocol: c2-16b\n    port: /dev/ttyUSB9\n"
    assert "no device of node" not in check_replay(tmp_path, c2).stderr  # sends whole nodes


def unfed(text: str, feeds: list[DeviceFeed], nodes: set[int] | None = None) -> list[str]:
    config = load_config_text(text, "crsf.yaml")
    found = unfed_slot_warnings(config, feeds, lambda name: name != "c2-16b", nodes)
    return [str(problem) for problem in found]


def t16000m(node_id: int, entry: Where | None = None) -> DeviceFeed:
    return DeviceFeed(
        "T.16000M", 0x044F, 0xB10A, node_id, frozenset({"x", "y", "slider", "rz"}), entry
    )


def test_a_slot_an_absent_pinned_entry_lists_is_awaited_not_unfed():
    text = CRSF_ON_T16000M + (
        "devices:\n"
        "  - {name: stick, match: {pid: 0xb10a}, node_id: 0, axes: {x: X, y: Y, rz: Rz}}\n"
        "  - {name: throttle, match: {pid: 0xb687}, node_id: 0, axes: {z: Z}}\n"
    )
    stick_entry = load_config_text(text, "crsf.yaml").devices[0].where
    assert unfed(text, [t16000m(0, stick_entry)]) == []  # the throttle's z: it warns itself
    assert len(unfed(CRSF_ON_T16000M, [t16000m(0)])) == 1


def test_only_the_nodes_asked_for_are_judged():
    text = CRSF_ON_T16000M.replace("node0.rz]", "node1.z]")
    assert len(unfed(text, [t16000m(0), t16000m(1)])) == 2
    (only,) = unfed(text, [t16000m(0), t16000m(1)], nodes={1})  # the daemon: the plugged one
    assert "node1.z reads axis z of node 1" in only
    assert unfed(text, [t16000m(2)]) == []  # nodes no device became: not judged
