"""A device whose reports are all refused (too short, an undeclared report ID) is in error
(docs/ICD.md "Device error codes", 0x06 BAD_REPORTS): `3` on its node and one log line per
run of BAD_REPORTS_LIMIT refused reports in a row; `!` while it lasts; good reports later
bring it back through the neutral guard. Black-box: a subprocess daemon on a replayed
T.16000M, a pty as the far end."""

from __future__ import annotations

from typing import Any

from daemon_harness import (
    StickState,
    data_frames,
    install,
    run_daemon,
    scale,
    service_frames,
    services,
    timed_recording,
)
from output_fakes import RecordingPort
from test_reader import RecordingDecoder

from usb2rc.hid.backend import DeviceGone, DeviceInfo
from usb2rc.hid.reader import BAD_REPORTS_LIMIT, DeviceReader
from usb2rc.protocols.c2_16b import codec as c2_16b

LIVE, FAILSAFE = c2_16b.LIVE, c2_16b.FAILSAFE
BAD_REPORTS = 0x06
REFUSED_LOG = "reports in a row were refused"


class Truncated:
    """The first bytes of a T.16000M report at rest: shorter than its descriptor declares."""

    def report(self) -> bytes:
        return StickState().report()[:5]


def errors(frames: list[Any], node_id: int = 0) -> list[c2_16b.ServiceFrame]:
    return [f for f in service_frames(frames, node_id) if f.service == c2_16b.Service.ERROR]


def bad_run(start_s: float, count: int, every_s: float = 0.005) -> list[tuple[float, Any]]:
    return [(start_s + i * every_s, Truncated()) for i in range(count)]


def test_a_device_with_only_bad_reports_sends_3_once_and_stays_failsafe(tmp_path, line, replay_dir):
    install(replay_dir / "stick.hid", timed_recording(bad_run(0.0, 3 * BAD_REPORTS_LIMIT)))
    daemon = run_daemon(tmp_path, line.path, replay_dir)
    try:
        line.wait_for(lambda fr: errors(fr))
        mark = len(line.frames())
        line.wait_for(lambda fr: len(data_frames(fr[mark:], 0)) >= 25)
        frames = line.frames()
        assert services(frames, 0) == [
            "connected",
            "vid-pid",
            "device-string",
            "device-type",
            "error",
        ]
        assert errors(frames)[0].error_code == BAD_REPORTS
        assert {f.status for f in data_frames(frames, 0)} == {FAILSAFE}
    finally:
        assert daemon.stop() == 0
    log = daemon.log()
    assert log.count(REFUSED_LOG) == 1
    assert "BAD_REPORTS" in log and "Thrustmaster T.16000M (044f:b10a)" in log


def test_good_reports_after_a_bad_run_bring_the_device_back_through_the_guard(
    tmp_path, line, replay_dir
):
    # live at rest, then held full left, then a run of bad reports, then good ones again:
    # full left first (not at rest: still `!`), centred at last (`>`)
    events: list[tuple[float, Any]] = [(0.0, StickState()), (1.0, StickState(x=0))]
    events += bad_run(1.5, 2 * BAD_REPORTS_LIMIT)
    events += [(2.5, StickState(x=0)), (3.5, StickState())]
    install(replay_dir / "stick.hid", timed_recording(events))
    daemon = run_daemon(tmp_path, line.path, replay_dir)
    try:
        line.wait_for(lambda fr: (own := data_frames(fr, 0)) and own[-1].axes[0] == -32768)
        line.wait_for(lambda fr: errors(fr))
        mark = len(line.frames())
        line.wait_for(lambda fr: (own := data_frames(fr[mark:], 0)) and own[-1].status == LIVE)
        line.wait_for(lambda fr: len(data_frames(fr[mark:], 0)) >= 5)
        frames = line.frames()
        in_error = data_frames(frames[frames.index(errors(frames)[0]) :], 0)
        back = next(i for i, f in enumerate(in_error) if f.status == LIVE)
        # until it rests again: `!`, holding the last good value (full left), never a jump
        assert all(f.status == FAILSAFE and f.axes[0] == -32768 for f in in_error[:back])
        assert in_error[back].axes[0] == scale(8192, 0, 16383)  # centred
        assert len(errors(frames)) == 1
        assert services(frames, 0)[4:] == ["error"]  # no `2`: it never was unplugged
    finally:
        assert daemon.stop() == 0
    log = daemon.log()
    assert log.count(REFUSED_LOG) == 1
    assert "understood again" in log and "node 0 waits for X centre" in log


# --- the reader's count, without a daemon ---------------------------------------------------


class ScriptedDevice:
    """Hands out its reports one per read, then is unplugged."""

    info = DeviceInfo(key="k", path="p", vid=0x044F, pid=0xB10A, product="S", port_path="1")

    def __init__(self, reports: list[bytes]) -> None:
        self.reports = list(reports)

    def read(self, timeout_s: float) -> bytes | None:
        if not self.reports:
            raise DeviceGone("done")
        return self.reports.pop(0)

    def open_output(self) -> RecordingPort:
        return RecordingPort()

    def close(self) -> None:
        pass


def test_the_reader_tells_each_edge_of_each_run_once():
    bad, good = [b"BAD"], [b"ok"]
    script = bad * BAD_REPORTS_LIMIT + good + bad * (BAD_REPORTS_LIMIT - 1) + good
    script += bad * (BAD_REPORTS_LIMIT + 5) + good
    edges: list[tuple[bool, int, int]] = []
    reader = DeviceReader(ScriptedDevice(script), RecordingDecoder(), lambda _r, _c: None)
    reader.on_bad_reports = lambda _r, rec: edges.append(
        (rec.in_error, rec.bad_spells, rec.refused_in_a_row)
    )
    reader.start()
    reader.join(10)
    assert not reader.is_alive()
    # a run of LIMIT - 1 is not one; a run in error is told when it begins and when it ends
    assert edges == [
        (True, 1, BAD_REPORTS_LIMIT),
        (False, 1, 0),
        (True, 2, BAD_REPORTS_LIMIT),
        (False, 2, 0),
    ]
    assert reader.record.bad_reports == 3 * BAD_REPORTS_LIMIT + 4
