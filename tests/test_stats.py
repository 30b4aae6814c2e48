"""Statistics: SIGUSR1 and `--stats-interval` log per-output and per-device figures
(`--stats-format json`: one JSON line per dump on stdout).

The daemon runs as a subprocess on real ptys (a C2-16B and a SUMD output) with a replayed
T.16000M; the far end sends garbage and a `<` request so the receive figures move too.
"""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from daemon_harness import (
    DaemonProcess,
    PtyLine,
    StickState,
    data_frames,
    expected_frame,
    install,
    recording,
    run_daemon,
    services,
)

from usb2rc.protocols.c2_16b import codec as c2_16b
from usb2rc.protocols.sumd import codec as sumd
from usb2rc.runtime import stats_text

STATES = [StickState(), StickState(x=0, buttons=1), StickState(x=16383, hat=4)]
GARBAGE = b"\x00noise\xff\x7e" * 3  # no 'H' in it: every byte is skipped
WAIT_S = 20.0

C2_LINE = re.compile(
    r"stats: output1-c2-16b (?P<url>\S+): writes (?P<writes>\d+), ticks (?P<ticks>\d+), "
    r"late (?P<late>\d+), missed (?P<missed>\d+), p99 \|period error\| (?P<p99>[\d.]+) ms, "
    r"p99 tick (?P<tick>[\d.]+) ms, bytes (?P<bytes>\d+), "
    r".*data frames (?P<data>\d+), service frames (?P<service>\d+), "
    r".*rx bytes (?P<rx>\d+), rx skipped (?P<skipped>\d+), "
    r"rx crc failures (?P<crc>\d+), requests (?P<requests>\d+)"
)
SUMD_LINE = re.compile(
    r"stats: output2-sumd (?P<url>\S+): writes (?P<writes>\d+), ticks (?P<ticks>\d+), "
    r"late (?P<late>\d+), .*p99 \|period error\| (?P<p99>[\d.]+) ms, "
    r"p99 tick (?P<tick>[\d.]+) ms, bytes (?P<bytes>\d+)"
)
DEVICE_LINE = re.compile(
    r"stats: device Thrustmaster T\.16000M \(replay-stick\): (?P<reports>\d+) reports "
    r"\((?P<rate>[\d.]+)/s avg\), bad (?P<bad>\d+), last report (?P<age>[\d.]+) s ago"
)


def wait_log(daemon: DaemonProcess, done) -> str:
    deadline = time.monotonic() + WAIT_S
    while not done(text := daemon.log()):
        if daemon.proc.poll() is not None or time.monotonic() > deadline:
            raise AssertionError(f"not in the log:\n{text}")
        time.sleep(0.05)
    return text


def two_outputs(tmp_path: Path, c2: PtyLine, sumd_line: PtyLine) -> Path:
    path = tmp_path / "two.yaml"
    path.write_text(
        "outputs:\n"
        f"  - {{protocol: c2-16b, port: {c2.path}}}\n"
        f"  - {{protocol: sumd, port: {sumd_line.path}}}\n"
    )
    return path


@pytest.fixture
def sumd_line():
    pty = PtyLine("sumd")
    yield pty
    pty.close_at_the_end()


def started(tmp_path, line, sumd_line, replay_dir, *extra: str) -> DaemonProcess:
    install(replay_dir / "stick.hid", recording(STATES))
    config = two_outputs(tmp_path, line, sumd_line)
    daemon = run_daemon(tmp_path, line.path, replay_dir, "--config", str(config), *extra)
    try:
        final = expected_frame(STATES[-1])
        line.wait_for(
            lambda fr: final in [(f.axes, f.group1, f.group2) for f in data_frames(fr, 0)], WAIT_S
        )
        sumd_line.wait_for(lambda fr: any(isinstance(f, sumd.SumdFrame) for f in fr), WAIT_S)
    except BaseException:
        daemon.stop()  # the caller's `try` has not begun: the daemon is ours to stop
        raise
    return daemon


def test_sigusr1_logs_output_device_and_receive_figures(tmp_path, line, sumd_line, replay_dir):
    daemon = started(tmp_path, line, sumd_line, replay_dir)
    try:
        # garbage, then a `<`: once the answer (a second connect sequence) is back, the
        # receiver has read the garbage in front of it too
        request = c2_16b.encode_data(c2_16b.CONFIG_REQUEST, 0, 0, [0] * 10, 0, 0)
        line.send(GARBAGE + request)
        line.wait_for(lambda fr: services(fr, 0).count("device-type") >= 2, WAIT_S)

        def data_after_answer(fr) -> int:
            types = [i for i, f in enumerate(fr) if getattr(f, "service", None) == 7]
            return len(data_frames(fr[types[1] :], 0)) if len(types) > 1 else 0

        # two data frames after the answer: the tick that wrote it has counted it
        line.wait_for(lambda fr: data_after_answer(fr) >= 2, WAIT_S)
        daemon.signal(signal.SIGUSR1)
        text = wait_log(daemon, lambda t: bool(DEVICE_LINE.search(t)))
        c2 = C2_LINE.search(text)
        assert c2, text
        assert c2["url"] == line.path
        # read while the output runs: a write may be counted a moment before its tick
        assert 0 < int(c2["writes"]) <= int(c2["ticks"]) + 1
        assert int(c2["late"]) >= 0 and int(c2["missed"]) >= 0
        assert float(c2["p99"]) >= 0.0
        assert 0.0 < float(c2["tick"]) < 20.0  # ticks ran, each well within its period
        assert int(c2["bytes"]) >= 36 * int(c2["writes"])  # at least one frame a write
        # frames sent: startup, the connect sequence, and its repeat for the `<` request
        assert int(c2["service"]) == 1 + 4 + 4
        assert 0 < int(c2["data"]) <= 6 * int(c2["writes"])  # 115200 baud: 6 frames a tick
        assert int(c2["skipped"]) == len(GARBAGE)
        assert int(c2["rx"]) >= len(GARBAGE) + len(request)
        assert int(c2["crc"]) == 0 and int(c2["requests"]) == 1

        s = SUMD_LINE.search(text)
        assert s, text
        assert s["url"] == sumd_line.path and int(s["writes"]) > 0
        frame_len = len(sumd.encode_sumd([12000] * 8))
        # one SUMD frame a write (the link counts its bytes a moment before the write counts)
        assert int(s["bytes"]) // frame_len in (int(s["writes"]), int(s["writes"]) + 1)

        dev = DEVICE_LINE.search(text)
        assert int(dev["reports"]) == len(STATES) and int(dev["bad"]) == 0
        assert float(dev["rate"]) > 0 and float(dev["age"]) >= 0
    finally:
        assert daemon.stop() == 0


def test_stats_interval_logs_periodically(tmp_path, line, sumd_line, replay_dir):
    daemon = started(tmp_path, line, sumd_line, replay_dir, "--stats-interval", "1")
    try:
        text = wait_log(daemon, lambda t: len(DEVICE_LINE.findall(t)) >= 2)
        assert len(C2_LINE.findall(text)) >= 2 and len(SUMD_LINE.findall(text)) >= 2
        # without any signal: the figures grow from one report to the next
        writes = [int(m["writes"]) for m in C2_LINE.finditer(text)]
        assert writes == sorted(writes) and writes[-1] > writes[0]
    finally:
        assert daemon.stop() == 0


def json_stats(text: str) -> list[dict]:
    return [json.loads(line)["stats"] for line in text.splitlines() if line.startswith('{"stats"')]


def test_sigusr1_with_json_stats_writes_one_json_line(tmp_path, line, sumd_line, replay_dir):
    daemon = started(tmp_path, line, sumd_line, replay_dir, "--stats-format", "json")
    try:
        daemon.signal(signal.SIGUSR1)
        text = wait_log(daemon, lambda t: len(json_stats(t)) >= 1)
        daemon.signal(signal.SIGUSR1)
        text = wait_log(daemon, lambda t: len(json_stats(t)) >= 2)
    finally:
        assert daemon.stop() == 0
    first, second = json_stats(text)
    assert "stats: output1" not in text  # json instead of the log lines, not as well
    c2, sumd_out = first["outputs"]
    assert (c2["name"], c2["url"]) == ("output1-c2-16b", line.path)
    assert (sumd_out["name"], sumd_out["url"]) == ("output2-sumd", sumd_line.path)
    assert "data_frames" in c2 and "data_frames" not in sumd_out  # C2-16B only
    (device,) = first["devices"]
    assert (device["name"], device["port_path"]) == ("Thrustmaster T.16000M", "replay-stick")
    assert (device["reports"], device["bad_reports"]) == (len(STATES), 0)
    # a fresh record each dump (the pty is not read now: the writes may have stalled)
    assert second["uptime_s"] > first["uptime_s"]
    # what usb2rc has taken of the host since it started, all threads and the drivers'
    assert first["cpu_pct"] > 0 and 0 < first["drivers_cpu_pct"] < 100
    assert first["drivers_cpu_pct"] <= first["cpu_pct"] + 1  # measured a moment apart
    assert stats_text.daemon_line(first).startswith(f"usb2rc: up {first['uptime_s']:.1f} s, CPU ")
    assert second["outputs"][0]["ticks"] >= c2["ticks"]
    # the log lines are the same record in words: the text format's regexes read them
    assert C2_LINE.search("stats: " + stats_text.output_line(c2))
    assert SUMD_LINE.search("stats: " + stats_text.output_line(sumd_out))
    assert DEVICE_LINE.search("stats: " + stats_text.device_line(device))


def test_json_stats_reader_going_away_does_not_stop_the_daemon(tmp_path, replay_dir):
    # `usb2rc run --stats-format json | head -1`: once head is gone, the stats go to the log
    install(replay_dir / "stick.hid", recording(STATES))
    log_path = tmp_path / "daemon.log"
    with open(log_path, "wb") as log_file:
        proc = subprocess.Popen(
            [sys.executable, "-m", "usb2rc", "run", "--replay", str(replay_dir), "--port",
             "loop://", "--stats-format", "json", "--stats-interval", "0.2"],
            stdout=subprocess.PIPE, stderr=log_file, stdin=subprocess.DEVNULL,
        )  # fmt: skip
        try:
            assert proc.stdout is not None
            assert json.loads(proc.stdout.readline())["stats"]["outputs"]
            proc.stdout.close()
            deadline = time.monotonic() + WAIT_S
            while "stats: output1-c2-16b loop://" not in log_path.read_text():
                assert proc.poll() is None, log_path.read_text()
                assert time.monotonic() < deadline, log_path.read_text()
                time.sleep(0.05)
            assert "stdout is gone" in log_path.read_text()
            proc.send_signal(signal.SIGTERM)
            assert proc.wait(timeout=WAIT_S) == 0
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
