"""The neutral guard's rest has a time, and zero config guards real gear (issue 19 point 10,
issue 20 point 3; docs/ICD.md, "Neutral guard").

- a stick swept through the centre is never "at rest": the guard wants every guarded axis
  inside its tolerance AND still (REST_SPAN) for REST_S, timed by the reports' times;
- the device database (usb2rc/data/devices.yaml): a DualShock 3 at rest (sticks off centre
  by its real offsets) goes live, a TWCS plugged with the throttle forward is `!` until
  pulled back, TFRP pedals at rest go live, all with zero config;
- a centre axis unmoved at an end since the plug (a quiz buzzer's X = Y = 0) gets one log
  line and a `monitor` hint naming the fix (`arm: any`).

The black-box tests run the daemon (or `monitor`) as a subprocess on hid-recorder files
written into tmp_path from real descriptors (tests/data/real-devices.json).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path

import pytest
from cli_harness import usb2rc
from daemon_harness import (
    PtyLine,
    RecordSource,
    StickState,
    data_frames,
    expected_frame,
    install,
    run_daemon,
    stick_record,
    timed_recording,
)
from hid_encoder import encode, ref_reports

from usb2rc.config import layout
from usb2rc.hid.backend import DeviceInfo
from usb2rc.hid.descriptor import parse_descriptor
from usb2rc.hid.reader import ReaderRecord
from usb2rc.hid.usages import (
    GD_DIAL,
    GD_GAMEPAD,
    GD_JOYSTICK,
    GD_RX,
    GD_RY,
    GD_RZ,
    GD_SLIDER,
    GD_X,
    GD_Y,
    GD_Z,
)
from usb2rc.nodes.binding import default_binding
from usb2rc.nodes.guard import (
    DEFAULT_TOLERANCE,
    FIXED_S,
    GAMEPAD_TOLERANCE,
    REST_S,
    default_tolerance,
)
from usb2rc.nodes.known_devices import all_devices, guard_axis, lookup, parse_devices
from usb2rc.nodes.table import NodeTable
from usb2rc.protocols.c2_16b import codec as c2_16b

LIVE, FAILSAFE = c2_16b.LIVE, c2_16b.FAILSAFE
DATA = Path(__file__).parent / "data" / "real-devices.json"
T16000M = "044f:b10a"


def real_descriptor(vid_pid: str) -> bytes:
    vid, pid = vid_pid.split(":")
    entry = next(d for d in json.loads(DATA.read_text()) if (d["vid"], d["pid"]) == (vid, pid))
    return bytes.fromhex(entry["hex"])


# --- the rest has a time (unit: the node table, its clock and the records' times) ----------


class Clock:
    """The node table's clock, moved by the test: frames at chosen times."""

    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def stick_table() -> tuple[NodeTable, RecordSource, Clock]:
    layout = parse_descriptor(real_descriptor(T16000M))
    clock = Clock()
    table = NodeTable(clock=clock)
    source = RecordSource(ReaderRecord(layout.initial_state(), 0))
    info = DeviceInfo("k0", "k0", 0x044F, 0xB10A, product="Thrustmaster T.16000M", port_path="1-1")
    table.add_device(0, info, default_binding(layout, "stick"), source, "JOYSTICK")
    return table, source, clock


def report_at(source: RecordSource, clock: Clock, state: StickState, reports: int) -> None:
    """A report the reader published now (its record carries the time, as a reader's does)."""
    record = stick_record(state, reports)
    source.record = ReaderRecord(record.state, reports, 0, clock.now)


def sweep_x(t: float) -> int:
    """X swept at full travel once a second, from full right (14-bit, centre 8192)."""
    return round(8192 + 8191 * math.cos(2 * math.pi * t))


def test_a_stick_swept_through_the_centre_never_arms() -> None:
    """A 1 Hz full-travel sweep, a report and a 50 Hz frame every 20 ms for 3 s: the stick
    passes the centre six times and the node stays `!`; held still at the centre it arms
    REST_S later. (Before the rest had a time the first frame near the centre armed it.)"""
    table, source, clock = stick_table()
    for tick in range(150):
        clock.now += 0.02
        report_at(source, clock, StickState(x=sweep_x(tick * 0.02)), tick + 1)
        assert table.frames()[0].failsafe, f"armed at t={tick * 0.02:.2f} s while sweeping"
    report_at(source, clock, StickState(), 1000)  # centred, then no report: it is still
    start = clock.now
    while clock.now - start < REST_S:
        assert table.frames()[0].failsafe
        clock.now += 0.01
    clock.now = start + REST_S + 0.001
    assert not table.frames()[0].failsafe


def test_a_resting_stick_arms_whichever_output_reads_it_and_however_often() -> None:
    """The rest is timed by the records and the frame's time, not counted in reads: a node
    read 100 times within REST_S stays `!`, one read after REST_S is `>`."""
    table, source, clock = stick_table()
    report_at(source, clock, StickState(x=8200), 1)  # near the centre, jitter of the sensor
    for _ in range(100):
        assert table.frames()[0].failsafe
    clock.now += REST_S / 2
    report_at(source, clock, StickState(x=8190), 2)  # still: within REST_SPAN of the first
    assert table.frames()[0].failsafe
    clock.now += REST_S / 2 + 0.001
    assert not table.frames()[0].failsafe


def test_a_rest_seen_report_by_report_counts_though_no_frame_read_it_in_time() -> None:
    """Centred at t0 and read at once; the next report (the very next one: count + 1) moves
    the stick 2 REST_S later: it had rested, so the device arms. After unseen reports (the
    count jumps) nothing is known of the time between: it does not."""
    for next_count, armed in ((2, True), (5, False)):
        table, source, clock = stick_table()
        report_at(source, clock, StickState(), 1)
        assert table.frames()[0].failsafe
        clock.now += 2 * REST_S
        report_at(source, clock, StickState(x=16383), next_count)
        assert table.frames()[0].failsafe is not armed, next_count


def test_a_move_during_the_rest_starts_it_again() -> None:
    table, source, clock = stick_table()
    report_at(source, clock, StickState(), 1)
    clock.now += REST_S * 0.8
    report_at(source, clock, StickState(x=8192 + 700), 2)  # +0.085: inside the tolerance
    assert table.frames()[0].failsafe  # ...but not still: the rest starts again
    clock.now += REST_S * 0.8
    assert table.frames()[0].failsafe
    assert table.describe()["0"]["waiting_for"] == [
        f"X, Y, Rz still for {REST_S:g} s (Thrustmaster T.16000M)"
    ]
    clock.now += REST_S * 0.2 + 0.001
    assert not table.frames()[0].failsafe


def test_a_centre_axis_unmoved_at_an_end_names_the_fix_after_fixed_s() -> None:
    """Held at full right by a hand: what it waits for, as before. Unmoved at the end for
    FIXED_S since the plug: the hint `arm: any` is added (a fixed axis, a button box)."""
    table, source, clock = stick_table()
    report_at(source, clock, StickState(x=16383), 1)
    assert table.frames()[0].failsafe
    assert table.describe()["0"]["waiting_for"] == ["X centre (Thrustmaster T.16000M)"]
    clock.now += FIXED_S
    assert table.frames()[0].failsafe
    (why,) = table.describe()["0"]["waiting_for"]
    assert why.startswith("X centre, X unmoved at an end since plugged")
    assert "set `arm: any` for it" in why


# --- tolerance by kind, the database --------------------------------------------------------


def test_a_game_pad_rests_looser_than_a_joystick() -> None:
    assert default_tolerance(GD_JOYSTICK) == DEFAULT_TOLERANCE == 0.1
    assert default_tolerance(GD_GAMEPAD) == GAMEPAD_TOLERANCE
    assert pytest.approx(7849 / 32767, abs=0.005) == GAMEPAD_TOLERANCE  # XInput's deadzone
    assert default_tolerance(GD_JOYSTICK, "gamepad") == GAMEPAD_TOLERANCE  # the database's


def test_every_database_entry_loads_with_a_source_and_a_rest_for_each_axis() -> None:
    devices = all_devices()
    assert len({(d.vid, d.pid) for d in devices}) == len(devices) >= 6
    for d in devices:
        assert d.source.strip() and d.name and d.axes
        assert all(a.arm in ("centre", "low", "high", "any") and a.role for a in d.axes)
    twcs = lookup(0x044F, 0xB687)
    assert twcs is not None and twcs.name.startswith("Thrustmaster TWCS")
    assert lookup(0x1234, 0x5678) is None


def test_a_malformed_entry_is_named() -> None:
    bad = {"devices": [{"vid": 1, "pid": 2, "name": "x", "kind": "pedals", "source": "s"}]}
    with pytest.raises(ValueError, match=r"devices\[0\]: needs exactly"):
        parse_devices(bad)
    entry = {"vid": 1, "pid": 2, "name": "x", "kind": "pedals", "source": "s"}
    bad = {"devices": [{**entry, "axes": {"Z": {"role": "rudder", "arm": "middle"}}}]}
    with pytest.raises(ValueError, match=r"devices\[0\]\.axes\.Z\.arm: 'middle'"):
        parse_devices(bad)


def test_a_config_arm_overrides_the_database() -> None:
    twcs = lookup(0x044F, 0xB687)
    from_db = guard_axis(2, "Z", GD_Z, GD_JOYSTICK, twcs)
    assert from_db is not None and (from_db.arm, from_db.label) == ("low", "Z (throttle)")
    assert guard_axis(2, "Z", GD_Z, GD_JOYSTICK, twcs, ("any", None)) is None
    assert guard_axis(2, "Z", GD_Z, GD_JOYSTICK, None) is None  # no entry: Z is not guarded


def test_describe_known_lists_the_database() -> None:
    out = usb2rc("describe", "--known")
    assert out.returncode == 0, out.stderr
    assert "044f:b687  Thrustmaster TWCS Throttle (throttle)" in out.stdout
    assert "source: usb.ids (044f:b687" in out.stdout
    out = usb2rc("describe", "--known", "--json")
    assert {(d["vid"], d["pid"]) for d in json.loads(out.stdout)} >= {("054c", "0268")}


# --- black box: replayed captures, zero config ---------------------------------------------


class Report:
    """One report of a real descriptor's input report, values by HID usage."""

    def __init__(self, descriptor: bytes, values: dict[int, int], report_id: int = 0) -> None:
        self.ref = ref_reports(descriptor)[report_id]
        self.values = {(usage, 0): v for usage, v in values.items()}

    def report(self) -> bytes:
        return encode(self.ref, self.values)


def capture(
    descriptor: bytes, ids: str, name: str, states: Callable[[float], dict[int, int]], **kw: int
) -> Callable[[float, float], str]:
    """A hid-recorder file of a device reporting every 20 ms from `start` to `end` s."""

    def text(start: float, end: float) -> str:
        times = [start + i * 0.02 for i in range(round((end - start) / 0.02))]
        events = [(t, Report(descriptor, states(t), kw.get("report_id", 0))) for t in times]
        return timed_recording(events, name, descriptor=descriptor, ids=ids)

    return text


def first_live(line: PtyLine, node_id: int = 0) -> int:
    """The index of the node's first `>` data frame (waits up to 20 s for it)."""
    line.wait_for(lambda fr: any(f.status == LIVE for f in data_frames(fr, node_id)), timeout=20)
    return [f.status for f in data_frames(line.frames(), node_id)].index(LIVE)


def assert_goes_live(tmp_path: Path, line: PtyLine, replay_dir: Path, file: str, text: str) -> None:
    """The daemon, zero config: the replayed device's node goes `>` (within 20 s)."""
    daemon = run_daemon(tmp_path, line.path, replay_dir)
    try:
        install(replay_dir / file, text)
        first_live(line)
    finally:
        assert daemon.stop() == 0, daemon.log()


def test_a_dualshock_3_at_rest_goes_live_with_zero_config(
    tmp_path: Path, line: PtyLine, replay_dir: Path
) -> None:
    """Its sticks rest at X +0.106, Y -0.129 of the half range (a public hid-recorder capture)
    with a count of jitter: inside the Game Pad tolerance, outside the joystick one."""
    descriptor = real_descriptor("054c:0268")
    jitter = [0, 1, 0, -1]

    def at_rest(t: float) -> dict[int, int]:
        j = jitter[round(t / 0.02) % 4]
        return {GD_X: 141 + j, GD_Y: 111, GD_Z: 128, GD_RZ: 128 - j}

    text = capture(descriptor, "054c 0268", "Sony PLAYSTATION(R)3 Controller", at_rest, report_id=1)
    assert_goes_live(tmp_path, line, replay_dir, "ds3.hid", text(0.0, 2.0))


def test_a_twcs_plugged_with_the_throttle_forward_waits_until_pulled_back(
    tmp_path: Path, line: PtyLine, replay_dir: Path
) -> None:
    """The TWCS throttle is HID Z (0..65535), idle at 0 (the database's `arm: low`, as
    data/config/hotas.yaml). Forward for 1 s after the plug: `!` with the held (failsafe)
    values; pulled back: `>`, and no live frame carries the forward throttle."""
    descriptor = real_descriptor("044f:b687")
    centred = {u: 512 for u in (GD_X, GD_Y, GD_RZ, GD_RX, GD_RY, GD_SLIDER, GD_DIAL)}

    def throttle(t: float) -> dict[int, int]:
        return {**centred, GD_Z: 65535 if t < 1.0 else 0}

    text = capture(descriptor, "044f b687", "TWCS Throttle", throttle, report_id=1)
    daemon = run_daemon(tmp_path, line.path, replay_dir)
    try:
        install(replay_dir / "twcs.hid", text(0.0, 2.0))
        live_at = first_live(line)
        frames = data_frames(line.frames(), 0)
        assert live_at >= 25  # forward for 1 s: ~50 ticks of `!`
        assert {f.status for f in frames[:live_at]} == {FAILSAFE}
        z_slot = layout.AXIS_NAMES.index("z")
        assert all(f.axes[z_slot] == -32768 for f in frames[live_at:] if f.status == LIVE)
    finally:
        assert daemon.stop() == 0, daemon.log()
    assert "node 0 waits for Z (throttle) low (TWCS Throttle)" in daemon.log()


# Thrustmaster TFRP: no public capture of its report descriptor was found, so this one is
# written from what public sources say of it (mdjarv/JoystickVisualizer: X the right toe
# brake, Y the left, Z the rudder; a Joystick collection): three 16-bit axes 0..1023.
TFRP_DESCRIPTOR = bytes.fromhex(
    "05010904a101"  # Generic Desktop, Joystick, Collection (Application)
    "0930093109321500 26ff03 75109503 8102".replace(" ", "")  # X, Y, Z 0..1023, 16 bit
    + "c0"
)


def test_tfrp_pedals_at_rest_go_live_with_zero_config(
    tmp_path: Path, line: PtyLine, replay_dir: Path
) -> None:
    """Rudder centred, toe brakes released (at an end): live. Without the database X and Y
    of a Joystick must rest at the centre, which released brakes never do."""

    def at_rest(t: float) -> dict[int, int]:
        return {GD_X: 0, GD_Y: 0, GD_Z: 512}

    text = capture(TFRP_DESCRIPTOR, "044f b678", "T.Flight Rudder Pedals", at_rest)
    assert_goes_live(tmp_path, line, replay_dir, "tfrp.hid", text(0.0, 1.0))


def test_a_stick_swept_at_full_travel_never_goes_live_end_to_end(
    tmp_path: Path, line: PtyLine, replay_dir: Path
) -> None:
    """A T.16000M plugged while its X is swept at full travel once a second for 3 s (a
    report every 10 ms), then left at the centre: every `>` frame is at the centre, and
    none comes during the sweep."""
    events = [(i * 0.01, StickState(x=sweep_x(i * 0.01))) for i in range(300)]
    events.append((3.0, StickState()))
    daemon = run_daemon(tmp_path, line.path, replay_dir)
    try:
        install(replay_dir / "stick.hid", timed_recording(events))
        live_at = first_live(line)
        frames = data_frames(line.frames(), 0)
        assert live_at >= 3.0 * 50 / 2  # 3 s of sweep at 50 Hz: well over half of it `!`
        centred = expected_frame(StickState())[0]
        assert all(f.axes == centred for f in frames if f.status == LIVE)
    finally:
        assert daemon.stop() == 0, daemon.log()


# A quiz buzzer: a Joystick collection whose X and Y are fixed at 0 (0..255), and 4 buttons.
BUZZER_DESCRIPTOR = bytes.fromhex(
    "05010904a101"  # Generic Desktop, Joystick, Collection (Application)
    "0930093115002600ff750895028102"  # X, Y 0..255, 8 bit
    "05091901290415002501750195048102"  # Buttons 1..4
    "750495018101"  # 4 bits padding
    "c0"
)


@pytest.mark.slow  # a long journey: the fast suite keeps shorter ones of its kind
def test_a_button_box_with_axes_fixed_at_an_end_is_told_the_fix(
    tmp_path: Path, line: PtyLine, replay_dir: Path
) -> None:
    """X = Y = 0 from the plug on: after FIXED_S one log line, and `monitor` shows the fix."""

    def fixed(t: float) -> dict[int, int]:
        return {GD_X: 0, GD_Y: 0}

    text = capture(BUZZER_DESCRIPTOR, "1234 0001", "Quiz Buzzer", fixed)(0.0, FIXED_S + 3)
    daemon = run_daemon(tmp_path, line.path, replay_dir)
    try:
        install(replay_dir / "buzzer.hid", text)
        line.wait_for(lambda fr: "arm: any" in daemon.log(), timeout=FIXED_S + 10)
    finally:
        assert daemon.stop() == 0, daemon.log()
    hints = [ln for ln in daemon.log().splitlines() if "set `arm: any`" in ln]
    assert len(hints) == 1, hints
    assert "node 0 waits for X centre, Y centre, X, Y unmoved at an end since plugged" in hints[0]
    monitor_dir = tmp_path / "monitor"
    monitor_dir.mkdir()
    install(monitor_dir / "buzzer.hid", text)
    seconds = str(FIXED_S + 1.5)
    out = usb2rc("monitor", "--replay", str(monitor_dir), "--seconds", seconds, "--plain")
    assert out.returncode == 0, out.stderr
    assert "set `arm: any` for it in a devices: entry (Quiz Buzzer)" in out.stdout
