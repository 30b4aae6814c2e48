"""No silent failsafe: a node in `!` because a pinned config entry has no device is said in
the log (within 5 s of start, then at most once a minute), in `stats` (text and JSON) and in
`monitor`'s node line. The journey: the shipped hotas.yaml on the demo recordings, which
have a stick and a throttle but no pedals (entry `pedals`, node 2)."""

from __future__ import annotations

import json
import re
import signal
from datetime import datetime
from pathlib import Path

from daemon_harness import ROOT, DaemonProcess, PtyLine, data_frames

from usb2rc.configfile import load_config
from usb2rc.daemon import expected_nodes
from usb2rc.nodes.missing import FIRST_WARNING_S, REPEAT_S, MissingWarnings
from usb2rc.nodes.table import MissingEntry, NodeTable

HOTAS = ROOT / "usb2rc" / "data" / "config" / "hotas.yaml"
DEMO = ROOT / "usb2rc" / "data" / "demo"
PEDALS_MATCH = "vid 0x044f, pid 0xb679"
# the line of the pedals' entry in the shipped file (its comments may grow)
PEDALS_LINE = next(
    n for n, line in enumerate(HOTAS.read_text().splitlines(), 1) if "- name: pedals" in line
)
WARNING = "missing: node 2 config entry 'pedals' (vid 0x044f, pid 0xb679; "
STAMP = re.compile(r"^(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3}) ", re.MULTILINE)


def log_time(line: str) -> datetime:
    match = STAMP.match(line)
    assert match, line
    return datetime.strptime(match.group(1), "%Y-%m-%d %H:%M:%S,%f")


def wait_for_log(daemon: DaemonProcess, line: PtyLine, text: str) -> str:
    """Wait (on the pty's frames as the clock that ticks) until the log holds `text`."""
    line.wait_for(lambda _frames: text in daemon.log(), timeout=20)
    return daemon.log()


def run_hotas(tmp_path: Path, line: PtyLine, *extra: str) -> DaemonProcess:
    args = ["--config", str(HOTAS), "--replay", str(DEMO), "--port", line.path, *extra]
    return DaemonProcess(args, tmp_path / "daemon.log")


def test_hotas_on_the_demo_warns_of_the_missing_pedals_within_5_s(tmp_path, line):
    daemon = run_hotas(tmp_path, line, "--stats-format", "json")
    try:
        log = wait_for_log(daemon, line, WARNING)
        line.wait_for(lambda fr: data_frames(fr, 2))  # node 2 is on the line, as `!`
        assert {f.status for f in data_frames(line.frames(), 2)} == {ord("!")}
        daemon.signal(signal.SIGUSR1)
        stats_line = '{"stats"'
        log = wait_for_log(daemon, line, stats_line)
    finally:
        assert daemon.stop() == 0
    lines = log.splitlines()
    warned = next(ln for ln in lines if WARNING in ln)
    # within 5 s of start, on the daemon's own clock (its first log line is its start)
    assert (log_time(warned) - log_time(lines[0])).total_seconds() < 5.0
    assert (
        "WARNING" in warned
        and f"{HOTAS}:{PEDALS_LINE}: devices[2]" in warned
        and "plug it in" in warned
    )
    assert log.count(WARNING) == 1  # once, not every tick (the next is a minute later)
    stats = json.loads(next(ln for ln in lines if ln.startswith(stats_line)))["stats"]
    assert stats["missing_devices"] == [
        {
            "node_id": 2,
            "entry": "pedals",
            "match": PEDALS_MATCH,
            "where": f"{HOTAS}:{PEDALS_LINE}: devices[2]",
        }
    ]


def test_text_stats_name_the_missing_entry(tmp_path, line):
    daemon = run_hotas(tmp_path, line)
    try:
        line.wait_for(lambda fr: data_frames(fr, 1))
        daemon.signal(signal.SIGUSR1)
        log = wait_for_log(daemon, line, "no device plugged, the node sends failsafe")
    finally:
        assert daemon.stop() == 0
    assert WARNING in log


def test_monitor_waits_for_the_entry_by_its_match():
    """`monitor`'s node line reads the table's `waiting_for` (FAILSAFE: waits for ...)."""
    table = NodeTable(expected_nodes(load_config(str(HOTAS))))
    waiting = table.describe()["2"]["waiting_for"]
    assert waiting == [f"pedals (not plugged: {PEDALS_MATCH})"]


def entry(node_id: int = 2, name: str = "pedals") -> MissingEntry:
    return MissingEntry(node_id, name, PEDALS_MATCH, f"hotas.yaml:{PEDALS_LINE}")


def test_warnings_come_after_the_grace_then_once_a_minute():
    warnings = MissingWarnings()
    start = 1000.0
    assert warnings.due([entry()], start) == []
    assert warnings.next_due() == start + FIRST_WARNING_S
    assert warnings.due([entry()], start + FIRST_WARNING_S) == [entry()]
    assert warnings.due([entry()], start + FIRST_WARNING_S + 1) == []  # not on every call
    assert warnings.due([entry()], start + FIRST_WARNING_S + REPEAT_S) == [entry()]
    # the device came: forgotten; missing again later (a reload): the grace starts over
    later = start + 500
    assert warnings.due([], later) == [] and warnings.next_due() is None
    assert warnings.due([entry()], later) == []
    assert warnings.due([entry()], later + FIRST_WARNING_S) == [entry()]
