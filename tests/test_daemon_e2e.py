"""End to end: the daemon as a subprocess, replayed devices, frames read off a real pty."""

from __future__ import annotations

import itertools

from daemon_harness import (
    StickState,
    data_frames,
    expected_frame,
    install,
    recording,
    run_daemon,
    service_frames,
    services,
)

from usb2rc import __version__
from usb2rc.hid import speedups
from usb2rc.protocols.c2_16b import codec as c2_16b

LIVE, FAILSAFE = c2_16b.LIVE, c2_16b.FAILSAFE

# Each state is held 100 ms (five 20 ms ticks), so every one must show up in the frames.
STATES = [
    StickState(),
    StickState(x=0, y=16383, buttons=0x0001),
    StickState(x=16383, y=0, rz=0, slider=255, buttons=0x8000),
    StickState(x=4000, y=12000, rz=255, slider=0, buttons=0x0101, hat=0),
    *[StickState(hat=direction) for direction in range(1, 8)],
    StickState(x=16383, y=16383, rz=200, slider=10, buttons=0xFFFF, hat=2),
]
FINAL = STATES[-1]


def is_subsequence(wanted: list, seen: list) -> bool:
    it = iter(seen)
    return all(any(w == s for s in it) for w in wanted)


def connect_sequence_at(frames: list, node_id: int, start: int = 0) -> int:
    """Index just past the first complete 1,6,5,7 sequence for node_id at or after start."""
    names = [
        (i, f.service.service_name)
        for i, f in enumerate(frames)
        if isinstance(f, c2_16b.ServiceFrame) and f.node_id == node_id and i >= start
    ]
    for k in range(len(names) - 3):
        if [n for _, n in names[k : k + 4]] == [
            "connected",
            "vid-pid",
            "device-string",
            "device-type",
        ]:
            return names[k + 3][0] + 1
    return -1


def test_plug_states_unplug_replug_and_sigterm(tmp_path, line, replay_dir):
    daemon = run_daemon(tmp_path, line.path, replay_dir)
    try:
        first = line.wait_for(lambda fr: fr[:1])
        assert first[0].service == c2_16b.Service.STARTUP
        assert first[0].node_id == 0xFF and first[0].text == f"usb2rc {__version__}"

        # each state held 0.25 s: on a loaded host a 0.1 s one may pass between two steps
        install(replay_dir / "stick.hid", recording(STATES, hold_s=0.25))
        line.wait_for(lambda fr: connect_sequence_at(fr, 0) > 0)
        frames = line.frames()
        connect = service_frames(frames, 0)[:4]
        assert (connect[1].vid, connect[1].pid) == (0x044F, 0xB10A)
        assert connect[2].text == "T.16000M"
        assert connect[3].text == "JOYSTICK"
        # no data frame of node 0 before its connect sequence
        end_of_connect = connect_sequence_at(frames, 0)
        assert not data_frames(frames[:end_of_connect], 0)

        # every replayed state reaches the line, in order, in the default layout
        # (docs/ICD.md, "Default axis layout" and "Default button layout")
        wanted = [expected_frame(s) for s in STATES]
        line.wait_for(
            lambda fr: (
                expected_frame(FINAL) in [(f.axes, f.group1, f.group2) for f in data_frames(fr, 0)]
            )
        )
        seen = [(f.axes, f.group1, f.group2) for f in data_frames(line.frames(), 0)]
        assert is_subsequence(wanted, seen)

        # message codes: 0 first, +1 per frame, rolling over 255 -> 0
        line.wait_for(lambda fr: len(data_frames(fr, 0)) >= 300, timeout=20)
        codes = [f.code for f in data_frames(line.frames(), 0)]
        assert codes[0] == 0
        assert all(b == (a + 1) % 256 for a, b in itertools.pairwise(codes))
        assert 255 in codes and codes.index(255) + 1 < len(codes)
        # `!` only until the device's first report has been read (its state unknown before)
        statuses = [f.status for f in data_frames(line.frames(), 0)]
        first_live = statuses.index(LIVE)
        assert set(statuses[:first_live]) <= {FAILSAFE} and set(statuses[first_live:]) == {LIVE}

        # unplug: `2`, then `!` frames: axes held, buttons and hat cleared
        count_before = len(line.frames())
        (replay_dir / "stick.hid").unlink()
        line.wait_for(lambda fr: "disconnected" in services(fr[count_before:], 0))
        line.wait_for(
            lambda fr: any(f.status == FAILSAFE for f in data_frames(fr[count_before:], 0))
        )
        after = line.frames()[count_before:]
        gone = services(after, 0).index("disconnected")
        failsafe = [f for f in data_frames(after, 0) if f.status == FAILSAFE]
        held_axes, _, _ = expected_frame(FINAL)
        assert all(f.axes == held_axes and f.group1 == 0 and f.group2 == 0 for f in failsafe)
        first_failsafe = after.index(failsafe[0])
        assert after.index(service_frames(after, 0)[gone]) < first_failsafe
        # after the `2`, no live frame of that node
        assert all(f.status == FAILSAFE for f in data_frames(after[first_failsafe:], 0))

        # replug: the same Node-ID, the connect sequence, then live frames again
        count_before = len(line.frames())
        install(replay_dir / "stick.hid", recording(STATES))
        line.wait_for(lambda fr: connect_sequence_at(fr, 0, count_before) > 0)
        line.wait_for(
            lambda fr: (
                data_frames(fr[count_before:], 0)[-1:]
                and data_frames(fr[count_before:], 0)[-1].status == LIVE
            )
        )
        assert {f.node_id for f in data_frames(line.frames())} == {0}
    finally:
        code = daemon.stop()
    assert code == 0, daemon.log()
    assert "stopped" in daemon.log()
    assert "Traceback" not in daemon.log()


def test_node_ids_follow_port_order_and_come_back(tmp_path, line, replay_dir):
    for name in ("a", "b"):
        install(replay_dir / f"{name}.hid", recording([StickState()]))
    daemon = run_daemon(tmp_path, line.path, replay_dir)
    try:
        line.wait_for(lambda fr: {0, 1} <= {f.node_id for f in data_frames(fr)})
        (replay_dir / "a.hid").unlink()
        line.wait_for(lambda fr: "disconnected" in services(fr, 0))
        install(replay_dir / "c.hid", recording([StickState()]))
        # node 0 is still in failsafe for "a": the new device gets the lowest *free* ID
        line.wait_for(lambda fr: any(f.node_id == 2 for f in data_frames(fr)))
        count_before = len(line.frames())
        install(replay_dir / "a.hid", recording([StickState()]))
        line.wait_for(lambda fr: connect_sequence_at(fr, 0, count_before) > 0)
        line.wait_for(
            lambda fr: [f.status for f in data_frames(fr[count_before:], 0)][-1:] == [LIVE]
        )
    finally:
        assert daemon.stop() == 0, daemon.log()


def test_without_a_port_exits_2_and_says_how(tmp_path, replay_dir):
    import subprocess
    import sys

    result = subprocess.run(
        [sys.executable, "-m", "usb2rc", "--replay", str(replay_dir)],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert result.returncode == 2
    assert "--port" in result.stderr


def test_every_state_reaches_the_line_with_the_c_loops_off(tmp_path, line, replay_dir):
    """The C loops are optional: a daemon started with them switched off (as on a machine
    that could not build them) decodes, steps and sends the same states, in order."""
    env = {speedups.PURE_PYTHON_ENV: "1"}
    daemon = run_daemon(tmp_path, line.path, replay_dir, env=env)
    try:
        install(replay_dir / "stick.hid", recording(STATES, hold_s=0.25))
        line.wait_for(
            lambda fr: (
                expected_frame(FINAL) in [(f.axes, f.group1, f.group2) for f in data_frames(fr, 0)]
            )
        )
        seen = [(f.axes, f.group1, f.group2) for f in data_frames(line.frames(), 0)]
        assert is_subsequence([expected_frame(s) for s in STATES], seen)
    finally:
        code = daemon.stop()
    assert code == 0, daemon.log()
    assert "the Python path runs" in daemon.log()  # switched off, or not built here
