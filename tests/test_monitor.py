"""`usb2rc monitor`: the daemon's input side shown live, in a real terminal and as text.

The terminal tests run the command on a tmux pane (when tmux is installed) and on a bare
pseudo-terminal with a fixed window size; a replayed T.16000M swings X from one end to the
other, and the screen must show both bars and values. They wait on what the screen shows,
never on the clock.
"""

from __future__ import annotations

import fcntl
import io
import os
import re
import select
import shutil
import struct
import subprocess
import sys
import termios
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from daemon_harness import ROOT, StickState, install, scale, timed_recording

from usb2rc.commands import monitor
from usb2rc.configfile import Config, load_config, load_config_text
from usb2rc.hid.backend import ErrorCode
from usb2rc.hid.replay import ReplayBackend
from usb2rc.nodes.table import EventKind, ServiceEvent

ROWS, COLS = 50, 140
LOW, HIGH = "-" * monitor.BAR_WIDTH, "#" * monitor.BAR_WIDTH
X_LINE = re.compile(r"^\s*x\s+\[([#-]+)\]\s+([+-]\d+)\s+raw\s+(-?\d+|-)\s+<- (.*)$", re.MULTILINE)
ANSI = re.compile(r"\x1b(\[[0-?]*[ -/]*[@-~]|\][^\x07]*\x07|[()][0-9A-Za-z]|[=>78])")
WAIT_S = 20.0

# X from one end to the other, each held 0.5 s (the last one 0.4 s), forever
# (--replay-loop); each lap starts centred for 0.3 s, so the neutral guard lets it go live.
SWING = timed_recording(
    [
        (0.0, StickState()),  # centred for a few 10 Hz snapshots: the guard lets it go live
        (0.3, StickState(x=0, buttons=0x0001)),
        (0.8, StickState(x=16383, hat=2)),
    ]
)


def swing_dir(tmp_path: Path) -> Path:
    folder = tmp_path / "replay"
    folder.mkdir()
    install(folder / "stick.hid", SWING)
    return folder


def monitor_argv(folder: Path, *extra: str) -> list[str]:
    return [
        sys.executable,
        "-m",
        "usb2rc",
        "monitor",
        "--replay",
        str(folder),
        "--replay-loop",
        *extra,
    ]


def x_lines(screen: str) -> set[tuple[str, int, str]]:
    return {(m[1], int(m[2]), m[4]) for m in X_LINE.finditer(screen)}


def x_raw_and_sent(screen: str) -> set[tuple[str, int]]:
    """(raw, sent) of each x line: the raw HID value beside the value it sends."""
    return {(m[3], int(m[2])) for m in X_LINE.finditer(screen)}


def both_ends_seen(screen: str) -> bool:
    seen = {(bar, value) for bar, value, _ in x_lines(screen)}
    ends = {("0", -32768), ("16383", 32767)}  # each raw end beside the value it sends
    return (LOW, -32768) in seen and (HIGH, 32767) in seen and ends <= x_raw_and_sent(screen)


def wait_until(read: Callable[[], str], done: Callable[[str], bool]) -> str:
    deadline = time.monotonic() + WAIT_S
    text = read()
    while not done(text):
        if time.monotonic() > deadline:
            raise AssertionError(f"the screen never showed it; last screen:\n{text}")
        time.sleep(0.05)
        text = read()
    return text


def screen_reader(fd: int, raw: bytearray) -> Callable[[], str]:
    """What came out of `fd` so far (gathered in `raw`, waiting a little for more), with
    the terminal's escapes taken out."""

    def screen() -> str:
        while select.select([fd], [], [], 0.05)[0]:
            try:
                chunk = os.read(fd, 65536)
            except OSError:
                break
            if not chunk:
                break
            raw.extend(chunk)
        return ANSI.sub("", raw.decode("utf-8", "replace")).replace("\r", "")

    return screen


def check_screen(screen: str) -> None:
    sources = {source for _, _, source in x_lines(screen)}
    reporting = {(raw, sent) for raw, sent in x_raw_and_sent(screen) if raw != "-"}
    ends = {("0", -32768), ("16383", 32767), ("8192", scale(8192, 0, 16383))}  # and centred
    ends.add(("8192", 0))  # centred, the guard's rest not over yet: `!` with 0 (docs/ICD.md)
    assert reporting <= ends, screen
    assert any(s.startswith("Thrustmaster T.16000M: X (raw 0..16383") for s in sources), sources
    assert "node 0" in screen and "LIVE" in screen
    assert "device Thrustmaster T.16000M (044f:b10a, port replay-stick)" in screen
    assert "buttons 1  hat centre" in screen or "buttons -  hat RIGHT" in screen
    assert "no serial port is opened" in screen


@pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed")
def test_live_view_in_tmux(tmp_path):
    folder = swing_dir(tmp_path)
    socket = f"usb2rc-test-{os.getpid()}"
    tmux = ["tmux", "-L", socket, "-f", os.devnull]
    command = " ".join(monitor_argv(folder, "--seconds", "60"))
    env = dict(os.environ, TERM="xterm", LANG="C.UTF-8")
    size = ["-x", str(COLS), "-y", str(ROWS)]
    subprocess.run(
        [*tmux, "new-session", "-d", "-s", "mon", *size, "-c", str(ROOT), command],
        check=True,
        env=env,
    )
    try:

        def screen() -> str:
            out = subprocess.run(
                [*tmux, "capture-pane", "-p", "-t", "mon"], capture_output=True, text=True
            )
            return out.stdout

        seen: list[str] = []

        def collect(text: str) -> bool:
            seen.append(text)
            return both_ends_seen("\n".join(seen))

        wait_until(screen, collect)
        check_screen("\n".join(seen))
        # one screen at a time: the pane never holds two different x lines
        assert all(len(x_lines(s)) <= 1 for s in seen)
    finally:
        subprocess.run([*tmux, "kill-server"], capture_output=True)


def test_live_view_on_a_pty(tmp_path):
    folder = swing_dir(tmp_path)
    master, slave = os.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", ROWS, COLS, 0, 0))
    env = dict(os.environ, TERM="xterm", LANG="C.UTF-8")
    env.pop("COLUMNS", None)
    env.pop("LINES", None)
    proc = subprocess.Popen(
        monitor_argv(folder, "--seconds", "60"),
        stdin=slave,
        stdout=slave,
        stderr=slave,
        cwd=ROOT,
        env=env,
        start_new_session=True,
    )
    os.close(slave)
    raw = bytearray()
    screen = screen_reader(master, raw)
    try:
        text = wait_until(screen, both_ends_seen)
        check_screen(text)
        assert "\x1b[" in raw.decode("utf-8", "replace")  # a live, redrawn screen
    finally:
        proc.terminate()
        proc.wait(10)
        os.close(master)


def test_plain_snapshots_when_not_a_terminal(tmp_path):
    folder = swing_dir(tmp_path)
    out = subprocess.run(
        monitor_argv(folder, "--seconds", "1.5", "--plain"),
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=60,
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.count("--- ") == 2  # at 0 s and 1 s
    assert "\x1b[" not in out.stdout
    check_screen(out.stdout)
    assert "event: node 0: connected Thrustmaster T.16000M" in out.stdout
    assert out.stdout.count("event: node 0: connected") == 1  # each event printed once


def wait_for(side: monitor.InputSide, done: Callable[[monitor.Snapshot], bool]):
    deadline = time.monotonic() + WAIT_S
    while not done(snap := side.snapshot()):
        assert time.monotonic() < deadline, monitor.snapshot_text(snap, [])
        time.sleep(0.02)
    return snap


def test_unplug_shows_failsafe_lost_device_and_events(tmp_path):
    folder = swing_dir(tmp_path)
    side = monitor.InputSide(Config.default(), ReplayBackend(folder, loop=True))
    side.start()
    try:
        snap = wait_for(side, lambda s: bool(s.nodes) and not s.nodes[0].failsafe)  # rested
        assert not side.daemon.outputs  # nothing is ever written anywhere
        assert [n.node_id for n in snap.nodes] == [0]
        (folder / "stick.hid").unlink()
        snap = wait_for(side, lambda s: s.nodes[0].failsafe)
        text = monitor.snapshot_text(snap, [])
        assert "node 0 FAILSAFE" in text
        assert "LOST (unplugged or failed)" in text
        assert "LOST: holds" in text  # default layout: the axes hold their last value
        assert "node 0: disconnected Thrustmaster T.16000M" in " ".join(side.events)
        install(folder / "stick.hid", SWING)
        snap = wait_for(side, lambda s: not s.nodes[0].failsafe)
        assert [n.node_id for n in snap.nodes] == [0]  # the same Node-ID comes back
        assert [e.split(":")[1].split()[0] for e in side.events] == [
            "connected",
            "disconnected",
            "connected",
        ]
    finally:
        side.stop()


def demo_snapshot(config_name: str, node_count: int) -> monitor.Snapshot:
    """A shipped config on the demo recordings, once its first node has both devices and is
    live (a device is not live before its first report)."""
    config = load_config(ROOT / "usb2rc" / "data" / "config" / config_name)
    side = monitor.InputSide(config, ReplayBackend(ROOT / "usb2rc" / "data" / "demo"))
    side.start()
    try:
        return wait_for(
            side,
            lambda s: (
                len(s.nodes) == node_count
                and len(s.nodes[0].devices) == 2
                and not s.nodes[0].failsafe
            ),
        )
    finally:
        side.stop()


def test_config_nodes_merged_devices_and_waiting_entry():
    snap = demo_snapshot("hotas.yaml", 2)
    text = monitor.snapshot_text(snap, [])
    stick, pedals = snap.nodes
    assert stick.node_id == 1 and not stick.failsafe
    assert "as stick" in text and "as throttle" in text
    slots = {a.slot: a.source for a in stick.axes}
    assert slots["x"].startswith("Thrustmaster T.16000M: X (raw 0..16383, deadband 0.02")
    assert slots["z"].startswith("Thrustmaster TWCS Throttle: Z")
    assert "aux1" in slots and "aux2" not in slots
    assert pedals.node_id == 2 and pedals.failsafe and pedals.waiting == ["pedals"]
    assert "waiting for config entry pedals: not plugged" in text


def test_the_hotas_demo_config_goes_live_on_the_demo_recordings():
    # hotas.yaml's pedals are not in the recordings (node 2 stays `!`); hotas-demo has none
    snap = demo_snapshot("hotas-demo.yaml", 1)
    assert snap.nodes[0].node_id == 1 and snap.nodes[0].waiting == []
    assert {a.slot for a in snap.nodes[0].axes} >= {"x", "y", "z", "rz", "aux1", "slider"}


def test_bar_and_event_text():
    assert monitor.bar(-32768, -32768, 32767) == LOW
    assert monitor.bar(32767, -32768, 32767) == HIGH
    assert monitor.bar(32768, 0, 65535, width=4) == "##--"
    assert monitor.bar(99999, 0, 65535, width=4) == "####"  # clamped
    error = ServiceEvent(EventKind.ERROR, 3, None, "", int(ErrorCode.READ_FAILED))
    assert monitor.event_text(error) == "node 3: error 0x01 (READ_FAILED)"
    odd = ServiceEvent(EventKind.ERROR, 3, None, "", 0x7F)
    assert monitor.event_text(odd) == "node 3: error 0x7f (unknown)"


TRIM_CONFIG = """
devices:
  - name: stick
    match: {vid: 0x044f, pid: 0xb10a}
    node_id: 1
    axes:
      x: {usage: X, trim_switch: {buttons: [3, 4], step: 0.05, limit: 0.1}}
      slider: {usage: Slider, arm: low}
"""


def test_monitor_shows_what_a_node_waits_for_and_its_trims(tmp_path):
    """Plugged with the slider up: `waits for Slider low`; then at rest, and button 4
    pressed three times: the trim steps +0.05 twice and stops at its limit, +0.1."""
    folder = tmp_path / "replay"
    folder.mkdir()
    up, low = StickState(slider=255), StickState(slider=0)
    presses = [
        (1.0 + 0.2 * k + dt, StickState(slider=0, buttons=b))
        for k in range(3)
        for dt, b in ((0, 8), (0.1, 0))
    ]
    install(folder / "stick.hid", timed_recording([(0.0, up), (0.5, low), *presses]))
    config = load_config_text(TRIM_CONFIG, "trim.yaml")
    side = monitor.InputSide(config, ReplayBackend(folder))
    side.start()
    try:
        snap = wait_for(side, lambda s: bool(s.nodes) and s.nodes[0].waits_for)
        text = monitor.snapshot_text(snap, [])
        assert "node 1 FAILSAFE: waits for Slider low (Thrustmaster T.16000M)" in text
        snap = wait_for(side, lambda s: "trim +0.100" in monitor.snapshot_text(s, []))
        assert not snap.nodes[0].failsafe
        x = next(a for a in snap.nodes[0].axes if a.slot == "x")
        assert x.value == scale(8192, 0, 16383) + 3277  # centred X, plus 0.1 of 32767.5
    finally:
        side.stop()


# --------------------------------------------------------------------------- 80 x 24


def fake_axis(slot: str, value: int) -> monitor.AxisRow:
    source = "Thrustmaster T.16000M FCS Hotas Stick Left Hand: X (raw 0..16383, expo 0.3)"
    return monitor.AxisRow(slot, value, -32768, 32767, source, raw=8192)


def fake_node(node_id: int, slots: int) -> monitor.NodeRow:
    axes = [fake_axis(slot, 1000 * i) for i, slot in enumerate(AXIS_NAMES[:slots])]
    return monitor.NodeRow(node_id, node_id % 2 == 1, [], ["pedals"], axes, [1, 2], "UP")


AXIS_NAMES = ("x", "y", "z", "rx", "ry", "rz", "slider", "dial", "aux1", "aux2")


def render_at(snap: monitor.Snapshot, logs: list[str], now: float, size=(80, 24)) -> list[str]:
    from rich.console import Console

    console = Console(width=size[0], height=size[1], record=True, file=io.StringIO())
    console.print(monitor.render_live(snap, logs, size, now))
    return console.export_text().rstrip("\n").split("\n")


def test_live_view_fits_80x24_and_pages_every_node():
    nodes = [fake_node(node_id, 8) for node_id in range(4)]  # 4 x 10 lines: two pages
    events = [f"node {i % 4}: connected" for i in range(30)]
    snap = monitor.Snapshot(nodes, events, len(events), ["stats line"] * 3)
    seen_titles: set[str] = set()
    for page in range(4):
        lines = render_at(snap, ["WARNING something"] * 5, now=page * monitor.PAGE_S)
        assert len(lines) <= 23 and all(len(line) <= 80 for line in lines), lines
        assert lines[0].startswith(f"page {page % 2 + 1}/2 (nodes ")
        seen_titles |= {line.split()[1] for line in lines if line.startswith("node ")}
        for line in lines:  # an axis line keeps its slot, whole bar, value and raw value
            if line.lstrip().startswith("x "):
                assert re.match(r"^\s*x\s+\[[#-]{16}\]\s+\+?\d+\s+raw\s+8192\s+<- ", line)
                assert line.endswith("<- X (raw 0..16383, expo 0.3)")  # the name gave way
        assert any("hidden" in line for line in lines)  # what is left out is counted
    assert seen_titles == {"0", "1", "2", "3"}


def test_live_view_at_80x24_shows_one_page_when_it_fits():
    snap = monitor.Snapshot([fake_node(0, 8)], ["node 0: connected"], 1)
    lines = render_at(snap, [], now=0.0)
    assert "page" not in lines[0] and len(lines) <= 23
    assert lines[-1] == "event: node 0: connected"
