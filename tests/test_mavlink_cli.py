"""`decode`, `icd` and `monitor` know the MAVLink output (docs/CONFIG.md, "MAVLink outputs";
docs/ICD.md, "MAVLink output"); `check`'s MAVLink problems are in
tests/data/configs/broken/mavlink-problems.yaml (test_check_icd_cli runs every broken config)."""

from __future__ import annotations

import json
import re
import socket
import subprocess
import sys
from pathlib import Path

from daemon_harness import ROOT, StickState, install, recording, scale
from test_check_icd_cli import usb2rc

from usb2rc.config.mavlink import MavlinkOptions
from usb2rc.protocols.mavlink.session import ControlValues, MavlinkEngine

GOOD = ROOT / "usb2rc" / "data" / "config" / "mavlink.yaml"


def session_bytes() -> list[bytes]:
    session = MavlinkEngine(MavlinkOptions(system_id=42, component_id=7))
    session.line_opened()
    return session.tick(0.0, ControlValues(False, channels=(1100, 1900))) + session.tick(
        0.02, ControlValues(True, channels=(1100, 1900))
    )


def test_decode_a_capture_as_json(tmp_path: Path) -> None:
    capture = tmp_path / "mav.bin"
    capture.write_bytes(b"noise" + b"".join(session_bytes()))
    out = usb2rc("decode", "--protocol", "mavlink", "--json", str(capture))
    assert out.returncode == 0, out.stderr
    records = [json.loads(line) for line in out.stdout.splitlines()]
    assert [r["message"] for r in records] == [
        "HEARTBEAT",
        "RC_CHANNELS_OVERRIDE",
        "RC_CHANNELS_OVERRIDE",
    ]
    assert {(r["system"], r["component"]) for r in records} == {(42, 7)}
    assert [r["seq"] for r in records] == [0, 1, 2]
    assert (records[1]["chan1_raw"], records[1]["chan2_raw"]) == (1100, 1900)
    assert records[2]["chan1_raw"] == 0 and records[2]["chan18_raw"] == 65534  # released
    assert "frames 3 (rc_channels_override 2, heartbeat 1), bytes skipped 5" in out.stderr


def test_decode_listens_on_udpin() -> None:
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "usb2rc",
            "decode",
            "--protocol",
            "mavlink",
            f"udpin:127.0.0.1:{port}",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )
    try:
        assert proc.stderr is not None and proc.stdout is not None
        assert "listening on" in proc.stderr.readline()  # bound: datagrams are not lost now
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
            for datagram in session_bytes():
                sender.sendto(datagram, ("127.0.0.1", port))
        lines = [proc.stdout.readline() for _ in range(3)]
        assert lines[0].startswith("mavlink HEARTBEAT from 42/7 seq 0: type=6 autopilot=8")
        assert "chan1_raw=1100 chan2_raw=1900 chan3_raw=65535" in lines[1]
        assert "chan1_raw=0" in lines[2] and "chan9_raw=65534" in lines[2]
    finally:
        proc.terminate()
        proc.wait(10)


def test_icd_describes_each_mavlink_output() -> None:
    out = usb2rc("icd", "--config", str(GOOD))
    assert out.returncode == 0, out.stderr
    text = out.stdout
    assert "## MAVLink output 1 (udpout:127.0.0.1:14550)" in text
    assert "| chan1_raw | node0.x | axis | 1000..2000 (centre 1500) |" in text
    assert "| chan5_raw | node0.button1 | button | 1000 / 2000 |" in text
    assert "every channel released (0 on 1-8, 65534 on 9-18) for 1 s" in text
    assert "| z | node1.z | axis | 0..1000 |" in text
    assert "| buttons bit 1 | node0.button2 | button | 1 pressed |" in text
    assert "no MANUAL_CONTROL, heartbeats only" in text
    # a UDP port has no baud rate; the serial one has its own (issue 20)
    assert "| mavlink | udpout:127.0.0.1:14550 | - (UDP) | 50 |" in text
    assert "| mavlink | /dev/ttyUSB0 | 57600 | 25 |" in text
    for command in ("icd", "check"):
        document = json.loads(usb2rc(command, "--config", str(GOOD), "--json").stdout)
        bauds = [out["baudrate"] for out in document["outputs"]]
        assert bauds == [None, 57600], (command, bauds)


def test_the_mavlink_example_names_files_that_exist_and_no_sitl_udp() -> None:
    """Its comments' commands run as written from the source tree (issue 20: they named a
    `config/` folder that does not exist), and plain SITL is TCP, not UDP 14550."""
    text = GOOD.read_text()
    named = re.findall(r"--config (\S+?)`", text)
    assert named and all((ROOT / path).is_file() for path in named), named
    assert "socket://127.0.0.1:5760" in text and "SITL listening on UDP" not in text


def test_monitor_shows_what_each_mavlink_output_would_send(tmp_path: Path) -> None:
    config = tmp_path / "m.yaml"
    config.write_text(
        "outputs:\n  - protocol: mavlink\n    port: udpout:127.0.0.1:9\n"
        "    channels: [node0.x, node0.rz, node0.button1, node3.x]\n"
        "  - protocol: mavlink\n    port: udpout:127.0.0.1:9\n    message: manual_control\n"
        "    channels: [node0.x, node0.y, node0.slider, node0.rz, node0.button1]\n"
    )
    replay = tmp_path / "replay"
    replay.mkdir()
    state = StickState(x=16383, y=0, rz=0, slider=255, buttons=1)
    # at rest first, for a few of monitor's 10 Hz looks: the guard's rest (docs/ICD.md)
    install(replay / "stick.hid", recording([StickState()] * 3 + [state]))
    out = usb2rc(
        "monitor", "--config", str(config), "--replay", str(replay), "--seconds", "1.5", "--plain"
    )
    assert out.returncode == 0, out.stderr
    assert scale(state.x, 0, 16383) == 32767  # full scale: x 1000
    # node 3 has no device: the override output is in failsafe; MANUAL_CONTROL reads node 0
    assert "mavlink udpout:127.0.0.1:9: FAILSAFE: releases every channel" in out.stdout
    assert "MANUAL_CONTROL x 1000 y -1000 z 1000 r -1000 buttons 0x00000001" in out.stdout


def test_monitor_outputs_shows_whom_a_udpin_output_answers(tmp_path: Path) -> None:
    """Before a vehicle calls, monitor --outputs says so, with what was ignored (issue 19)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    config = tmp_path / "m.yaml"
    config.write_text(f"outputs:\n  - protocol: mavlink\n    port: udpin:127.0.0.1:{port}\n")
    replay = tmp_path / "replay"
    replay.mkdir()
    args = ["--config", str(config), "--replay", str(replay), "--outputs", "--seconds", "1"]
    out = usb2rc("monitor", *args, "--plain")
    assert out.returncode == 0, out.stderr
    assert "peer none (no vehicle has called yet)" in out.stdout
    assert "from others ignored 0, not allowed 0" in out.stdout


def test_pymavlink_is_imported_only_with_a_mavlink_output() -> None:
    """The registry names MAVLink's decoder and build function as strings: the daemon, the
    config and the commands load without pymavlink's 2 MB dialect (a Pi's start time)."""
    code = (
        "import sys\n"
        "import usb2rc.daemon, usb2rc.configfile, usb2rc.wiring\n"
        "from usb2rc.commands import check, decode, icd, monitor\n"
        "print(sorted(m for m in sys.modules if m.startswith('pymavlink')))\n"
        "from usb2rc.outputs import protocol\n"
        "protocol('mavlink').decoder()\n"
        "print('pymavlink' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split("\n")[:2] == ["[]", "True"]
