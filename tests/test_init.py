"""`usb2rc init`: the starter config maps each device exactly as the default layout does,
says where each line comes from, passes `check`, and never replaces a file unasked."""

from __future__ import annotations

import dataclasses
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from daemon_harness import ROOT, StickState, install, recording

from usb2rc.cli import main
from usb2rc.commands.init import read_devices
from usb2rc.commands.starter import PluggedDevice, starter_config
from usb2rc.configfile import load_config_text
from usb2rc.hid.descriptor import InputState
from usb2rc.hid.recording import read_recording
from usb2rc.nodes.binding import default_axis_fields, default_binding
from usb2rc.nodes.mapping import compile_mapping

DEMO = ROOT / "usb2rc" / "data" / "demo"


def recorded_states(path: Path, layout_device: PluggedDevice) -> list[InputState]:
    decoder = layout_device.layout.make_decoder()
    states = []
    for event in read_recording(path).events:
        assert decoder.feed(event.report)
        states.append(decoder.state())
    return states


def test_each_entry_maps_its_device_as_the_default_layout_does():
    plugged, skipped = read_devices(str(DEMO))
    assert skipped == [] and len(plugged) == 2
    config = load_config_text(starter_config(plugged, "/dev/null"), "x.yaml")
    mapping = compile_mapping(config)
    for dev, recording_file in zip(plugged, ("stick.hid", "throttle.hid"), strict=True):
        written = mapping.bind(dev.info, dev.layout)
        assert written is not None and written.name != dev.info.product  # its own entry
        default = default_binding(dev.layout, "default")
        assert written.axis_info == default.axis_info
        assert written.hat_notes == default.hat_notes
        for state in recorded_states(DEMO / recording_file, dev):  # 2000 reports each
            assert written.apply(state) == default.apply(state)


def test_nodes_are_pinned_in_port_order_and_the_output_is_on_the_port():
    plugged, _ = read_devices(str(DEMO))
    config = load_config_text(starter_config(plugged, "/dev/ttyAMA0"), "x.yaml")
    assert [d.node_id for d in config.devices] == [0, 1]
    assert [(d.match.vid, d.match.pid) for d in config.devices] == [
        (p.info.vid, p.info.pid) for p in plugged
    ]
    assert all(d.match.serial is None and d.match.port is None for d in config.devices)
    (output,) = config.outputs
    assert (output.protocol, output.port, output.rate_hz) == ("c2-16b", "/dev/ttyAMA0", 50)


def test_every_axis_line_names_its_usage_and_logical_range():
    plugged, _ = read_devices(str(DEMO))
    text = starter_config(plugged, None)
    for dev in plugged:
        for slot, field in default_axis_fields(dev.layout):
            pattern = rf"^\s+{slot}:\s+\{{usage: \w+\}}\s+# \w+, logical "
            pattern += rf"{field.logical_min}\.\.{field.logical_max}, {field.bit_size} bits$"
            assert re.search(pattern, text, re.MULTILINE), (slot, text)
    assert "# port: " in text  # no --port: the port is left to `run --port`
    assert load_config_text(text, "x.yaml").outputs[0].port is None


def test_two_alike_devices_are_told_apart_by_serial(tmp_path):
    for name in ("left.hid", "right.hid"):
        shutil.copy(DEMO / "stick.hid", tmp_path / name)
    plugged, _ = read_devices(str(tmp_path))
    config = load_config_text(starter_config(plugged, None), "x.yaml")
    assert [d.match.serial for d in config.devices] == ["left", "right"]
    assert [d.name for d in config.devices] == ["thrustmaster-t-16000m", "thrustmaster-t-16000m-2"]
    mapping = compile_mapping(config)
    assert [mapping.entry_for(p.info).name for p in plugged] == [d.name for d in config.devices]


def test_alike_devices_without_serials_are_told_apart_by_port():
    plugged, _ = read_devices(str(DEMO))
    stick = plugged[0]
    twins = [
        dataclasses.replace(
            stick, info=dataclasses.replace(stick.info, key=p, serial="", port_path=p)
        )
        for p in ("1-1.2", "1-1.3")
    ]
    config = load_config_text(starter_config(twins, None), "x.yaml")
    assert [d.match.port for d in config.devices] == ["1-1.2", "1-1.3"]
    assert [d.match.serial for d in config.devices] == [None, None]


def test_awkward_product_names_and_ports_stay_strings(tmp_path):
    name = 'Joy: "Pro" #1 - yes'
    install(tmp_path / "joy.hid", recording([StickState()], name=name))
    plugged, _ = read_devices(str(tmp_path))
    port = "/dev/serial/by-id/usb-FTDI_#1: not a comment"  # a path pyserial takes as it is
    text = starter_config(plugged, port)
    config = load_config_text(text, "x.yaml")
    assert config.devices[0].name == "joy-pro-1-yes"
    assert config.outputs[0].port == port
    assert f"# {name} 044f:b10a" in text


# --------------------------------------------------------------------------- the command


def init(*args: str) -> int:
    return main(["init", "--replay", str(DEMO), *args])


def test_writes_a_file_check_accepts(tmp_path, capsys):
    out = tmp_path / "x.yaml"
    assert init("--port", "/dev/ttyUSB0", "-o", str(out)) == 0  # /dev/null is no serial line
    assert "wrote" in capsys.readouterr().err
    assert main(["check", "--config", str(out), "--replay", str(DEMO)]) == 0
    assert "node 0 as 'thrustmaster-t-16000m'" in capsys.readouterr().out


def test_refuses_to_replace_a_file_without_force(tmp_path, capsys):
    out = tmp_path / "x.yaml"
    out.write_text("# mine\n")
    assert init("-o", str(out)) == 2
    assert "exists; --force replaces it" in capsys.readouterr().err
    assert out.read_text() == "# mine\n"
    assert init("-o", str(out), "--force") == 0
    assert out.read_text().startswith("# usb2rc config written by `usb2rc init`")


def test_without_output_prints_the_config(capsys):
    assert init("--port", "/dev/serial0") == 0
    text = capsys.readouterr().out
    assert load_config_text(text, "<stdout>").outputs[0].port == "/dev/serial0"


def test_no_devices_and_a_missing_folder(tmp_path, capsys):
    assert main(["init", "--replay", str(tmp_path)]) == 1
    assert "No devices" in capsys.readouterr().err
    with pytest.raises(SystemExit) as usage_error:  # argparse: --replay's type check
        main(["init", "--replay", str(tmp_path / "nope")])
    assert usage_error.value.code == 2
    assert "no such directory" in capsys.readouterr().err


def test_from_a_fresh_process_init_then_check(tmp_path):
    """The issue's own acceptance commands, as a user types them."""
    usb2rc = [sys.executable, "-m", "usb2rc"]
    demo = "usb2rc/data/demo"
    out = tmp_path / "x.yaml"
    made = subprocess.run(
        [*usb2rc, "init", "--replay", demo, "--port", "/dev/ttyUSB0", "-o", str(out)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert made.returncode == 0, made.stderr
    checked = subprocess.run(
        [*usb2rc, "check", "--config", str(out)], capture_output=True, text=True, timeout=60
    )
    assert checked.returncode == 0, checked.stderr
    assert "node 1: thrustmaster-twcs-throttle: axes x y z slider rx ry rz dial" in checked.stdout


@pytest.mark.parametrize("count", [0, 16, 30, 60])
def test_buttons_follow_the_default_runs_up_to_the_devices_last(count):
    plugged, _ = read_devices(str(DEMO))
    stick = plugged[0]
    layout = dataclasses.replace(stick.layout, button_count=count)
    text = starter_config([PluggedDevice(stick.info, layout)], None)
    (entry,) = load_config_text(text, "x.yaml").devices
    assert [(r.hid, r.node) for r in entry.buttons] == [
        (b, b) for b in range(1, min(count, 56) + 1)
    ]
    assert ("buttons 57-60" in text) == (count == 60)


def test_a_replaced_file_keeps_its_mode_and_leaves_no_temporary(tmp_path):
    from usb2rc.runtime.textfile import write_atomically

    target = tmp_path / "usb2rc.yaml"
    target.write_text("old\n")
    target.chmod(0o640)
    write_atomically(target, "new\n")
    assert target.read_text() == "new\n"
    assert target.stat().st_mode & 0o777 == 0o640
    assert [p.name for p in tmp_path.iterdir()] == ["usb2rc.yaml"]


# --------------------------------------------------------------------------- --port


@pytest.mark.parametrize("port", ["/dev/null", "/dev/zero", "DIR", "FILE"])
def test_a_port_that_cannot_be_a_serial_line_is_refused(tmp_path, capsys, port):
    """The daemon would retry such a port forever (issue 20): init refuses it, exit 2, and
    says how to leave the port out instead."""
    (tmp_path / "FILE").write_text("")
    port = {"DIR": str(tmp_path), "FILE": str(tmp_path / "FILE")}.get(port, port)
    out = tmp_path / "x.yaml"
    with pytest.raises(SystemExit) as exited:
        init("--port", port, "-o", str(out))
    assert exited.value.code == 2
    err = capsys.readouterr().err
    assert f"{port!r} cannot be a serial line" in err and "leave --port out" in err
    assert not out.exists()


def test_a_pty_an_absent_adapter_and_a_url_are_ports(tmp_path, capsys):
    import os

    leader, follower = os.openpty()
    try:
        for port in (os.ttyname(follower), "/dev/ttyUSB97", "socket://127.0.0.1:5760"):
            out = tmp_path / "x.yaml"
            assert init("--port", port, "-o", str(out), "--force") == 0, capsys.readouterr()
            assert load_config_text(out.read_text(), "x.yaml").outputs[0].port == port
    finally:
        os.close(leader)
        os.close(follower)


def test_without_a_port_the_config_says_how_to_give_it(tmp_path, capsys):
    out = tmp_path / "x.yaml"
    assert init("-o", str(out)) == 0
    assert "# port: /dev/serial0" in out.read_text() and "usb2rc run --port PORT" in out.read_text()
    assert load_config_text(out.read_text(), "x.yaml").outputs[0].port is None
