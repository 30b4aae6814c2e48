"""A reload (SIGHUP) while a stick is live, judged on the wire (docs/ICD.md "A reload and the
live devices"): a subprocess daemon on a replayed T.16000M, a pty as the far end, C2-16B
frames decoded with usb2rc.protocols.c2_16b.codec.Decoder.

- re-pinned (node 4 -> 5): node 4 says `2` and sends `!`, node 5 announces the device
  (`1`,`6`,`5`,`7`) and goes `>` once the stick rests;
- re-pinned while deflected: node 5 sends `!` with its failsafe values until the stick rests;
- its axes mapped differently while deflected: no full-travel step, `!` holding the values
  sent before the reload until the stick rests;
- a reload that leaves its axes as they were: not one `!`.
"""

from __future__ import annotations

import itertools
import signal
from pathlib import Path
from typing import Any

from daemon_harness import (
    INVERT_X_CONFIG,
    DaemonProcess,
    PtyLine,
    StickState,
    data_frames,
    install,
    run_daemon,
    services,
    timed_recording,
)
from test_lifecycle import ScriptedBackend, make_reader, plug_stick

from usb2rc.configfile import Config, load_config_text
from usb2rc.daemon import expected_nodes
from usb2rc.nodes.lifecycle import DeviceLifecycle
from usb2rc.nodes.mapping import compile_mapping
from usb2rc.nodes.table import EventKind, NodeTable
from usb2rc.protocols.c2_16b import codec as c2_16b

LIVE, FAILSAFE = c2_16b.LIVE, c2_16b.FAILSAFE
CONNECT = ["connected", "vid-pid", "device-string", "device-type"]
FULL_LEFT = -32768  # X at 0 of 0..16383 (docs/ICD.md, "Axis scaling")

PINNED = """
devices:
  - name: stick
    match: {{vid: 0x044f, pid: 0xb10a}}
    node_id: {node}
"""
REST_S = 1.0  # the stick rests this long after it is plugged (the guard arms), then moves


def plug(replay_dir: Path, deflect: bool) -> None:
    """A T.16000M at rest; with `deflect`, held full left from REST_S on."""
    events: list[tuple[float, StickState]] = [(0.0, StickState())]
    if deflect:
        events.append((REST_S, StickState(x=0)))
    install(replay_dir / "stick.hid", timed_recording(events))


def start(tmp_path: Path, line: PtyLine, replay_dir: Path, text: str) -> tuple[Path, DaemonProcess]:
    config = tmp_path / "usb2rc.yaml"
    config.write_text(text)
    return config, run_daemon(tmp_path, line.path, replay_dir, "--config", str(config))


def reload(line: PtyLine, daemon: DaemonProcess, config: Path, text: str) -> int:
    """Write the config and SIGHUP; returns how many frames the far end had before."""
    count = len(line.frames())
    config.write_text(text)
    daemon.signal(signal.SIGHUP)
    return count


def finish(daemon: DaemonProcess) -> str:
    """Stop the daemon (exit 0); its log, which holds no traceback."""
    assert daemon.stop() == 0
    log = daemon.log()
    return log


def last_data(frames: list[Any], node_id: int) -> c2_16b.DataFrame | None:
    own = data_frames(frames, node_id)
    return own[-1] if own else None


def live_at(node_id: int, x: int | None = None) -> Any:
    """A wait condition: the node's last frame is `>` (with X at `x`)."""

    def ready(frames: list[Any]) -> bool:
        last = last_data(frames, node_id)
        return last is not None and last.status == LIVE and x in (None, last.axes[0])

    return ready


def after_sequence(frames: list[Any], node_id: int) -> list[c2_16b.DataFrame]:
    """The node's data frames after its connect sequence's last frame (`7`)."""
    for i, frame in enumerate(frames):
        if (
            isinstance(frame, c2_16b.ServiceFrame)
            and frame.node_id == node_id
            and frame.service == c2_16b.Service.DEVICE_TYPE
        ):
            return data_frames(frames[i + 1 :], node_id)
    return []


def codes_count_on(frames: list[c2_16b.DataFrame]) -> bool:
    codes = [f.code for f in frames]
    return all(b == (a + 1) % 256 for a, b in itertools.pairwise(codes))


def test_a_repinned_live_stick_moves_to_its_new_node(tmp_path, line, replay_dir):
    plug(replay_dir, deflect=False)
    config, daemon = start(tmp_path, line, replay_dir, PINNED.format(node=4))
    try:
        line.wait_for(live_at(4))
        count = reload(line, daemon, config, PINNED.format(node=5))
        line.wait_for(lambda fr: len(after_sequence(fr[count:], 5)) >= 10 and live_at(5)(fr))
        after = line.frames()[count:]
        assert services(after, 4) == ["disconnected"]
        assert services(after, 5) == CONNECT
        # node 4: `!` from its `2` on (and never `>` again); node 5: `>` only after its `7`
        gone = next(i for i, f in enumerate(after) if isinstance(f, c2_16b.ServiceFrame))
        assert {f.status for f in data_frames(after[gone:], 4)} == {FAILSAFE}
        line.wait_for(lambda fr: len(data_frames(fr[count + gone :], 4)) >= 10)
        assert {f.status for f in data_frames(line.frames()[count + gone :], 4)} == {FAILSAFE}
        announced = after_sequence(line.frames()[count:], 5)
        before = len(data_frames(after, 5)) - len(after_sequence(after, 5))
        assert all(f.status == FAILSAFE for f in data_frames(after, 5)[:before])
        assert announced[-1].status == LIVE
    finally:
        log = finish(daemon)
    assert "moves from Node-ID 4 to Node-ID 5" in log


def test_a_stick_repinned_while_deflected_waits_to_rest_on_its_new_node(tmp_path, line, replay_dir):
    plug(replay_dir, deflect=True)
    config, daemon = start(tmp_path, line, replay_dir, PINNED.format(node=4))
    try:
        line.wait_for(live_at(4, FULL_LEFT))
        count = reload(line, daemon, config, PINNED.format(node=5))
        line.wait_for(lambda fr: len(after_sequence(fr[count:], 5)) >= 25)
        after = line.frames()[count:]
        assert services(after, 5) == CONNECT
        node5 = data_frames(after, 5)
        # a new stick on node 5, held full left: never live, never its deflection; the
        # entry's failsafe values (none configured: 0) until it rests
        assert {f.status for f in node5} == {FAILSAFE}
        assert {f.axes[0] for f in node5} == {0}
        assert services(after, 4) == ["disconnected"]
    finally:
        log = finish(daemon)
    assert "node 5 waits for X centre" in log


def test_a_reload_that_maps_a_deflected_axis_differently_makes_no_step(tmp_path, line, replay_dir):
    plug(replay_dir, deflect=True)
    config, daemon = start(tmp_path, line, replay_dir, INVERT_X_CONFIG.format(invert="false"))
    try:
        line.wait_for(live_at(4, FULL_LEFT))
        count = reload(line, daemon, config, INVERT_X_CONFIG.format(invert="true"))
        line.wait_for(lambda fr: (last := last_data(fr[count:], 4)) and last.status == FAILSAFE)
        mark = len(line.frames())
        line.wait_for(lambda fr: len(data_frames(fr[mark:], 4)) >= 25)
        after = data_frames(line.frames()[count:], 4)
        # inverted, the stick held full left would send full right (+32767): it holds what
        # it sent (full left) as `!` until X centres, the same device on the same node
        assert {f.axes[0] for f in after} == {FULL_LEFT}
        assert {f.status for f in data_frames(line.frames()[mark:], 4)} == {FAILSAFE}
        assert not services(line.frames()[count:], 4)
        assert codes_count_on(data_frames(line.frames(), 4))
    finally:
        log = finish(daemon)
    assert "axes map differently now" in log and "node 4 enters failsafe" in log
    assert "waiting for X centre" in log


def test_a_reload_that_leaves_the_axes_as_they_were_keeps_a_deflected_stick_live(
    tmp_path, line, replay_dir
):
    plug(replay_dir, deflect=True)
    config, daemon = start(tmp_path, line, replay_dir, INVERT_X_CONFIG.format(invert="false"))
    try:
        line.wait_for(live_at(4, FULL_LEFT))
        # another entry, and a failsafe value for X: nothing this stick sends changes
        pedals = PINNED.format(node=6).replace("devices:\n", "").replace("stick", "pedals")
        text = INVERT_X_CONFIG.format(invert="false").replace("invert: false", "failsafe: 0")
        count = reload(line, daemon, config, text + pedals.replace("b10a", "b679"))
        line.wait_for(lambda fr: len(data_frames(fr[count:], 6)) >= 25)
        after = data_frames(line.frames()[count:], 4)
        assert {(f.status, f.axes[0]) for f in after} == {(LIVE, FULL_LEFT)}
        assert codes_count_on(data_frames(line.frames(), 4))
    finally:
        log = finish(daemon)
    assert "reloaded" in log


# --- a move that cannot be made, on the lifecycle alone --------------------------------------


def test_a_second_stick_of_a_repinned_entry_stays_on_its_node(tmp_path, caplog):
    """Two identical sticks on automatic IDs; a reload pins their entry to node 4: the first
    (in key order) moves, the second would be a second device of that entry on node 4, so
    it stays where it is with its previous mapping, and the log says why."""
    table = NodeTable()
    lifecycle = DeviceLifecycle(
        ScriptedBackend(tmp_path), table, compile_mapping(Config.default()), make_reader
    )
    lifecycle.plugged(plug_stick(tmp_path, "a.hid"))
    lifecycle.plugged(plug_stick(tmp_path, "b.hid"))
    lifecycle.handle_queued()
    try:
        assert [(n, i.port_path) for n, i, _b, _p, _t in table.attachments()] == [
            (0, "replay-a"),
            (1, "replay-b"),
        ]
        cursor = table.step_if_due().log.end  # after the connect sequences
        pinned = load_config_text(PINNED.format(node=4), "pinned.yaml")
        assert lifecycle.reload(compile_mapping(pinned), expected_nodes(pinned))
        where = [(n, i.port_path, b.name) for n, i, b, _p, _t in table.attachments()]
        assert where == [(1, "replay-b", "Thrustmaster T.16000M"), (4, "replay-a", "stick")]
        events = table.step_if_due().log.since(cursor)
        assert events is not None
        assert [(e.kind, e.node_id) for e in events] == [
            (EventKind.DISCONNECTED, 0),
            (EventKind.CONNECTED, 4),
        ]
        assert "stays on Node-ID 1 with its previous mapping" in caplog.text
    finally:
        for reader in lifecycle.shutdown(5.0):
            reader.join(5.0)
