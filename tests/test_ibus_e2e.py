"""End to end: the daemon as a subprocess with an `ibus` output on a pty, over two replayed
devices; the far end decodes with the reference decoder written from the description
(tests/ibus_reference.py). The channels follow the sticks, an unplug of a listed node's
device silences the line (iBus's failsafe: no frames), a replug brings the frames back."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from daemon_harness import (
    PtyLine,
    StickState,
    data_frames,
    expected_frame,
    install,
    recording,
    run_daemon,
)
from ibus_reference import RefIbusReader, microseconds

from usb2rc.protocols.c2_16b import codec as c2_16b

WAIT_S = 20.0
STICK_A = [StickState(), StickState(x=2000, y=16383, buttons=1)]
STICK_B = [StickState(), StickState(rz=200)]
CHANNELS = "[node0.x, node0.y, node1.rz, node0.button1]"


class IbusLine(PtyLine):
    """The far end of the iBus line, read by the reference decoder only."""

    def __init__(self) -> None:
        self.reference = RefIbusReader()
        super().__init__()

    def _received(self, now: float, data: bytes, frames: list[Any]) -> None:
        decoded = self.reference.feed(data)
        if decoded:
            self._record(now, decoded)


def expected(a: StickState, b: StickState) -> list[int]:
    """The 14 channels from the documented scaling (docs/ICD.md, "iBus output")."""
    axes_a, group1_a, _ = expected_frame(a)
    axes_b, _, _ = expected_frame(b)
    button = 2000 if group1_a & 1 else 1000
    listed = [microseconds(axes_a[0]), microseconds(axes_a[1]), microseconds(axes_b[6]), button]
    return listed + [1000] * 10


def test_ibus_follows_the_stick_goes_silent_on_unplug_and_comes_back(
    tmp_path: Path, line: PtyLine, replay_dir: Path
) -> None:
    install(replay_dir / "a.hid", recording(STICK_A))
    install(replay_dir / "b.hid", recording(STICK_B))
    ibus_line = IbusLine()
    config = tmp_path / "ibus.yaml"
    config.write_text(
        "outputs:\n"
        f"  - {{protocol: c2-16b, port: {line.path}}}\n"
        f"  - {{protocol: ibus, port: {ibus_line.path}, channels: {CHANNELS}}}\n"
        "devices:\n"
        "  - {name: a, match: {port: replay-a}, node_id: 0}\n"
        "  - {name: b, match: {port: replay-b}, node_id: 1}\n"
    )
    live = expected(STICK_A[-1], STICK_B[-1])
    try:
        daemon = run_daemon(tmp_path, line.path, replay_dir, "--config", str(config))
    except BaseException:
        ibus_line.close()
        raise
    try:
        ibus_line.wait_for(lambda fr: fr and fr[-1].channels == live, WAIT_S)

        # unplug device b (node 1, listed): the line goes silent
        (replay_dir / "b.hid").unlink()
        # the c2-16b line says when node 1 is in failsafe; from then on iBus sends nothing
        line.wait_for(
            lambda fr: (f := data_frames(fr, 1)[-1:]) and f[0].status == c2_16b.FAILSAFE, WAIT_S
        )
        silent_from = len(ibus_line.frames())
        # 30 more C2-16B frames of node 0 (0.6 s at 50 Hz): still no iBus frame but at most
        # the one tick that was under way
        at = len(line.frames())
        line.wait_for(lambda fr: len(fr) >= at + 30, WAIT_S)
        assert len(ibus_line.frames()) <= silent_from + 1

        # replug: frames again, following the sticks
        install(replay_dir / "b.hid", recording(STICK_B))
        ibus_line.wait_for(lambda fr: len(fr) > silent_from + 1 and fr[-1].channels == live, WAIT_S)
    finally:
        code = daemon.stop()
        ibus_line.close()
    assert code == 0, daemon.log()
    assert "Traceback" not in daemon.log()
    assert ibus_line.reference.bad_checksums == 0
