"""Fault injection on the running daemon (subprocess, pty, replayed devices), repeated.

Each test repeats its fault several times (USB2RC_FAULT_REPEATS) and checks, on the far end
of the line (stress_harness.CheckedLine): no crash, the right service and failsafe frames,
message codes consecutive per node (no frame lost), no data frame of a node that was never
announced (no frame invented), no byte skipped and no CRC failure. Recovery times are
measured with time.monotonic and reported (asserted only against generous bounds).
"""

from __future__ import annotations

import math
import os
import random
import signal
import time
from pathlib import Path

import pytest
from daemon_harness import (
    INVERT_UNGUARDED_X_CONFIG,
    INVERT_X_CONFIG,
    DaemonProcess,
    StickState,
    install,
    recording,
    scale,
)
from stress_harness import (
    CheckedLine,
    elapsed,
    env_int,
    figures,
    proc_stats,
    summarize,
    terminate,
)

from usb2rc.protocols.c2_16b import codec as c2_16b

pytestmark = pytest.mark.slow

LIVE, FAILSAFE = c2_16b.LIVE, c2_16b.FAILSAFE
REPEATS = env_int("USB2RC_FAULT_REPEATS", 5)


@pytest.fixture
def replay(tmp_path: Path) -> Path:
    folder = tmp_path / "replay"
    folder.mkdir()
    return folder


def start(tmp_path: Path, port: str, replay: Path, *extra: str) -> DaemonProcess:
    return DaemonProcess(["--port", port, "--replay", str(replay), *extra], tmp_path / "d.log")


def finish(daemon: DaemonProcess) -> str:
    code, _ = terminate(daemon.proc)
    daemon.stop()
    log = daemon.log()
    assert code == 0, log[-2000:]
    assert "Traceback" not in log, log[-4000:]
    return log


def live(node: int):
    return lambda ln: ln.node(node).status == LIVE


# The neutral guard arms once the stick has rested still for 0.05 s (docs/ICD.md "Neutral
# guard"), as its reader sees it: a drained batch can start the rest late, so rest 0.3 s.
REST_S = 0.3


def fast_states(n: int, seed: int, hold_s: float) -> list[StickState]:
    """REST_S at rest (the neutral guard lets the stick go live once its reader sees it
    resting long enough, docs/ICD.md "Neutral guard"), then n random states."""
    rng = random.Random(seed)
    resting = math.ceil(REST_S / hold_s)
    return [StickState()] * resting + [
        StickState(x=rng.randrange(16384), y=rng.randrange(16384), buttons=rng.randrange(65536))
        for _ in range(n)
    ]


# --- the serial line ------------------------------------------------------------------------


def test_serial_line_vanishes_and_returns(request, tmp_path, replay):
    install(replay / "stick.hid", recording([StickState(), StickState(x=0)]))
    link = tmp_path / "ttyLINK"
    line = CheckedLine()
    link.symlink_to(line.path)
    daemon = start(tmp_path, str(link), replay)
    to_first, to_live, sessions = [], [], []
    try:
        line.wait_for(lambda ln: ln.node(0).data_frames >= 10)
        for _ in range(REPEATS):
            link.unlink()
            line.close()
            sessions.append(line)
            time.sleep(random.uniform(0.1, 1.5))  # gone for a while (several ticks)
            line = CheckedLine()
            t0 = time.monotonic()
            link.symlink_to(line.path)
            line.wait_for(lambda ln: ln.startups, timeout=15)
            line.wait_for(live(0), timeout=15)
            to_first.append(line.startups[0] - t0)
            to_live.append(line.node(0).first_status_after(t0, LIVE) - t0)
            line.wait_for(lambda ln: ln.node(0).data_frames >= 10)
            assert line.node(0).names()[:4] == [
                "connected",
                "vid-pid",
                "device-string",
                "device-type",
            ]
            line.assert_clean()
    finally:
        sessions.append(line)
        log = finish(daemon)
        line.close()
    assert log.count("is back") == REPEATS
    figures(
        request,
        "fault-serial-line",
        {
            "outages": REPEATS,
            "back_to_startup_frame": summarize(to_first),
            "back_to_live_frame": summarize(to_live),
        },
    )
    assert max(to_live) < 10


# --- devices --------------------------------------------------------------------------------


def test_unplug_mid_report_at_high_rate(request, tmp_path, replay):
    """A 2 kHz recording removed while it plays: `2`, `!` with held axes, replug live."""
    states = fast_states(400, 1, 0.0005)
    text = recording(states, hold_s=0.0005)  # 2 kHz, 0.2 s, then held
    install(replay / "fast.hid", text)
    line = CheckedLine()
    daemon = start(tmp_path, line.path, replay, "--replay-loop")
    replug, failsafe_after = [], []
    wire = {(scale(s.x, 0, 16383), scale(s.y, 0, 16383)) for s in states}
    try:
        line.wait_for(live(0))
        for k in range(REPEATS):
            time.sleep(random.uniform(0.05, 0.5))
            t0 = time.monotonic()
            os.unlink(replay / "fast.hid")
            line.wait_for(lambda ln, t0=t0: ln.node(0).first_status_after(t0, FAILSAFE), timeout=10)
            failsafe_after.append(line.node(0).first_status_after(t0, FAILSAFE) - t0)
            line.wait_for(lambda ln: ln.node(0).data_frames and ln.node(0).status == FAILSAFE)
            with line.locked():
                node = line.node(0)
                assert node.last_group1 == 0  # buttons clear in failsafe
                assert node.names()[-1] == "disconnected"
                x, y = node.last_axes[0], node.last_axes[1]
            # axes held at one of the recorded states (scaled 0..16383 -> int16)
            assert (x, y) in wire, (x, y, line.summary())
            t1 = time.monotonic()
            states = fast_states(400, k + 2, 0.0005)
            wire = {(scale(s.x, 0, 16383), scale(s.y, 0, 16383)) for s in states}
            install(replay / "fast.hid", recording(states, hold_s=0.0005))
            line.wait_for(lambda ln, t1=t1: ln.node(0).first_status_after(t1, LIVE), timeout=10)
            replug.append(line.node(0).first_status_after(t1, LIVE) - t1)
        line.assert_clean()
        node = line.node(0)
        assert node.names().count("disconnected") == REPEATS
        assert node.connect_sequences == REPEATS + 1
    finally:
        finish(daemon)
        line.close()
    figures(
        request,
        "fault-unplug-mid-report",
        {
            "unplugs": REPEATS,
            "unplug_to_failsafe": summarize(failsafe_after),
            "replug_to_live": summarize(replug),
        },
    )


def test_device_whose_reads_fail(request, tmp_path, replay):
    """read-error 0.3 s after each open: error `3` (0x01), `2`, `!`, reopened, live, again."""
    text = recording(
        [StickState(), StickState(x=0, buttons=1)], extra="# usb2rc-fault: read-error at 0.3"
    )
    install(replay / "bad.hid", text)
    install(
        replay / "good.hid", recording([StickState(), StickState(x=16383)], name="Good T.16000M")
    )
    line = CheckedLine()
    daemon = start(tmp_path, line.path, replay)
    cycles = max(3, REPEATS)
    try:

        def errors(ln):
            return [s for s in ln.node(0).services if s[1] == "error"]

        line.wait_for(lambda ln: len(errors(ln)) >= cycles, timeout=30 + 3 * cycles)
        line.wait_for(lambda ln: ln.node(0).connect_sequences >= cycles)
        with line.locked():
            node, other = line.node(0), line.node(1)
            seen_errors = errors(line)
            assert all(code == 0x01 for _, _, code in seen_errors)
            names = node.names()
            # every error is followed by its `2` and a connect sequence when reopened
            for i, name in enumerate(names):
                if name == "error" and i + 1 < len(names):
                    assert names[i + 1] == "disconnected"
            recover = []
            for t, name, _ in node.services:
                if name == "error":
                    back = node.first_status_after(t, LIVE)
                    if back:
                        recover.append(back - t)
            assert other.status == LIVE and "error" not in other.names()
            assert FAILSAFE in [s for _, s in node.status_changes]
        line.assert_clean()
    finally:
        finish(daemon)
        line.close()
    figures(
        request,
        "fault-read-errors",
        {"read_errors": len(seen_errors), "error_to_live_again": summarize(recover)},
    )


def test_device_flooding_8khz(request, tmp_path, replay):
    """8 kHz reports (looped): the reader keeps up, ticks keep their rate, codes consecutive."""
    states = fast_states(800, 3, 0.000125)  # 0.1 s at 8 kHz, looped
    # no pause at a lap's start (a streaming device that pauses 0.5 s is silent: `!`, 0x07)
    install(replay / "flood.hid", recording(states, hold_s=0.000125, rest_s=0.000125))
    seconds = env_int("USB2RC_FLOOD_SECONDS", 10)
    line = CheckedLine()
    daemon = start(tmp_path, line.path, replay, "--replay-loop", "--stats-interval", str(seconds))
    try:
        line.wait_for(live(0))
        n0, t0 = line.node(0).data_frames, time.monotonic()
        time.sleep(seconds)
        n1, t1 = line.node(0).data_frames, time.monotonic()
        stats = proc_stats(daemon.proc.pid)
        line.wait_for(lambda ln: True)
        deadline = time.monotonic() + 15
        while "reports (" not in daemon.log() and time.monotonic() < deadline:
            time.sleep(0.2)
        line.assert_clean()
        assert line.node(0).status == LIVE
    finally:
        log = finish(daemon)
        line.close()
    rate = [ln for ln in log.splitlines() if "reports (" in ln]
    reports_per_s = float(rate[-1].split("reports (")[1].split("/s")[0]) if rate else 0.0
    frames_per_s = (n1 - n0) / (t1 - t0)
    figures(
        request,
        "fault-flood-8khz",
        {
            "seconds": seconds,
            "reports_per_s": reports_per_s,
            "frames_per_s": round(frames_per_s, 1),
            "daemon": stats.as_dict(),
        },
    )
    assert frames_per_s > 25  # nominal 50; generous on a shared machine
    assert reports_per_s > 1000


def test_ten_devices_at_115200(request, tmp_path, replay):
    """10 nodes, 6 frames per tick: round-robin, every node served, one bandwidth warning."""
    for i in range(10):
        install(
            replay / f"s{i}.hid",
            recording([StickState(), StickState(x=i * 1000)], name=f"Stick {i:02d}"),
        )
    line = CheckedLine()
    daemon = start(tmp_path, line.path, replay)
    try:
        line.wait_for(lambda ln: all(ln.node(n).connect_sequences for n in range(10)), timeout=20)
        line.wait_for(lambda ln: all(ln.node(n).data_frames >= 100 for n in range(10)), timeout=60)
        line.assert_clean()
        before = {n: line.node(n).data_frames for n in range(10)}
        t0, c0 = time.monotonic(), line.data_frames_total()
        time.sleep(4)
        total_rate = (line.data_frames_total() - c0) / (time.monotonic() - t0)
        counts = {n: line.node(n).data_frames - before[n] for n in range(10)}
        line.assert_clean()
    finally:
        log = finish(daemon)
        line.close()
    warnings = [ln for ln in log.splitlines() if "round-robin" in ln]
    assert len(warnings) == 1, warnings
    assert "230400 baud would carry them all" in warnings[0]
    assert min(counts.values()) > 0  # every node served in every window
    assert max(counts.values()) - min(counts.values()) <= 0.2 * max(counts.values()) + 2
    figures(
        request,
        "fault-ten-devices-115200",
        {"data_frames_per_s_all_nodes": round(total_rate, 1), "per_node_in_4_s": counts},
    )
    assert total_rate < 6 * 50 + 5  # never more than the line carries


def test_rx_garbage_and_requests_interleaved(request, tmp_path, replay):
    install(replay / "a.hid", recording([StickState()]))
    install(replay / "b.hid", recording([StickState(), StickState(x=1)], name="Other T.16000M"))
    line = CheckedLine()
    daemon = start(tmp_path, line.path, replay)
    rng = random.Random(9)
    rounds = env_int("USB2RC_RX_ROUNDS", 60)
    sent = {"config": 0, "poll_present": 0, "poll_absent": 0}
    latency = []
    try:
        line.wait_for(lambda ln: live(0)(ln) and live(1)(ln))
        for _ in range(rounds):
            garbage = rng.randbytes(rng.randint(0, 200))
            kind = rng.choice(list(sent))
            if kind == "config":
                req = c2_16b.encode_data(c2_16b.CONFIG_REQUEST, 0x10, 0, [0] * 10, 0, 0)
            elif kind == "poll_present":
                req = c2_16b.poll_request(rng.choice((0, 1)))
            else:
                req = c2_16b.poll_request(rng.randint(2, 250))
            split = rng.randrange(len(req))
            before = sum(ln.connect_sequences for ln in line.nodes.values())
            absent_before = sum(ln.names().count("disconnected") for ln in line.nodes.values())
            t0 = time.monotonic()
            line.send(garbage + req[:split])
            time.sleep(0.01)
            line.send(req[split:] + rng.randbytes(rng.randint(0, 50)))
            sent[kind] += 1

            def answered(ln, before=before, absent_before=absent_before, kind=kind):
                seqs = sum(n.connect_sequences for n in ln.nodes.values())
                absent = sum(n.names().count("disconnected") for n in ln.nodes.values())
                want = {"config": 2, "poll_present": 1, "poll_absent": 0}[kind]
                return seqs >= before + want and absent >= absent_before + (kind == "poll_absent")

            line.wait_for(answered, timeout=10)
            latency.append(time.monotonic() - t0)
        time.sleep(0.5)
        total = sum(ln.connect_sequences for ln in line.nodes.values())
        assert total == 2 + 2 * sent["config"] + sent["poll_present"]  # none lost, none extra
        line.assert_clean()
    finally:
        finish(daemon)
        line.close()
    figures(request, "fault-rx-garbage", {"requests": sent, "answer_latency": summarize(latency)})


def test_sighup_storm(request, tmp_path, replay):
    config = tmp_path / "usb2rc.yaml"
    config.write_text(INVERT_UNGUARDED_X_CONFIG.format(invert="false"))
    install(replay / "stick.hid", recording([StickState(), StickState(x=0)]))
    line = CheckedLine(configured=[4])
    daemon = start(tmp_path, line.path, replay, "--config", str(config))
    storms = env_int("USB2RC_SIGHUP_STORMS", 6)
    visible = []
    sighups = 0
    try:
        line.wait_for(lambda ln: live(4)(ln) and ln.node(4).last_axes[0] == -32768)
        for k in range(storms):
            for j in range(20):  # a burst: bad and good configs, no pause
                config.write_text(
                    INVERT_UNGUARDED_X_CONFIG.format(invert="maybe" if j % 3 == 0 else "false")
                )
                daemon.signal(signal.SIGHUP)
                sighups += 1
            invert = k % 2 == 0
            config.write_text(
                INVERT_UNGUARDED_X_CONFIG.format(invert="true" if invert else "false")
            )
            t0 = time.monotonic()
            daemon.signal(signal.SIGHUP)
            sighups += 1
            want = 32767 if invert else -32768
            line.wait_for(lambda ln, w=want: ln.node(4).last_axes[0] == w, timeout=20)
            visible.append(time.monotonic() - t0)
        line.wait_for(lambda ln: ln.node(4).data_frames > 50)
        line.assert_clean()
        assert daemon.proc.poll() is None
    finally:
        log = finish(daemon)
        line.close()
    assert "rejected" in log
    figures(
        request,
        "fault-sighup-storm",
        {"sighups": sighups, "reload_to_mapping_visible": summarize(visible)},
    )


# --- SIGTERM at any moment ------------------------------------------------------------------


def test_sigterm_at_random_moments(request, tmp_path, replay):
    rng = random.Random(env_int("USB2RC_FUZZ_SEED", 20240601))
    runs = env_int("USB2RC_SIGTERM_RUNS", 16)
    config = tmp_path / "c.yaml"
    config.write_text(INVERT_X_CONFIG.format(invert="false"))
    exits, moments = [], {}
    t_start = time.monotonic()
    for i in range(runs):
        moment = ["start-up", "plug", "unplug", "reload"][i % 4]
        for f in replay.iterdir():
            f.unlink()
        if moment != "plug":
            install(replay / "stick.hid", recording(fast_states(50, i, 0.002), hold_s=0.002))
        line = CheckedLine(configured=[4])
        daemon = DaemonProcess(
            ["--port", line.path, "--replay", str(replay), "--config", str(config)],
            tmp_path / f"d{i}.log",
        )
        try:
            if moment == "start-up":
                # after the signal handlers exist (the first frame is on the line); before
                # that a SIGTERM kills the interpreter: see test_sigterm_before_handlers
                line.wait_for(lambda ln: ln.startups, timeout=20)
                time.sleep(rng.uniform(0, 0.3))
            else:
                line.wait_for(lambda ln: ln.startups, timeout=20)
                if moment == "plug":
                    install(
                        replay / "stick.hid", recording(fast_states(50, i, 0.002), hold_s=0.002)
                    )
                elif moment == "unplug":
                    line.wait_for(live(4), timeout=20)
                    os.unlink(replay / "stick.hid")
                else:
                    daemon.signal(signal.SIGHUP)
                time.sleep(rng.uniform(0, 0.25))
            code, took = terminate(daemon.proc, timeout=10)
            daemon.stop()
        finally:
            if daemon.proc.poll() is None:  # a failed wait: never leak a daemon into later ptys
                daemon.proc.kill()
                daemon.proc.wait()
            line.close()
        log = daemon.log()
        assert code == 0, (moment, code, log[-2000:])
        assert "Traceback" not in log, log
        exits.append(took)
        moments[moment] = moments.get(moment, 0) + 1
    figures(
        request,
        "fault-sigterm",
        {
            "runs": runs,
            "moments": moments,
            "exit_time": summarize(exits),
            "seconds": elapsed(t_start),
        },
    )
    assert max(exits) < 5


def _catches_sigterm(pid: int) -> bool:
    status = Path(f"/proc/{pid}/status").read_text()
    caught = int(next(ln for ln in status.splitlines() if ln.startswith("SigCgt:")).split()[1], 16)
    return bool(caught >> (signal.SIGTERM - 1) & 1)


def test_sigterm_before_handlers(tmp_path, replay):
    """A SIGTERM as soon as usb2rc's code runs (imports still going on) is a clean stop.

    Before that moment the interpreter itself is starting and nothing of usb2rc exists to
    catch it; the test sends it at the first moment a handler is installed."""
    line = CheckedLine()
    daemon = DaemonProcess(["--port", line.path, "--replay", str(replay)], tmp_path / "d.log")
    try:
        while not _catches_sigterm(daemon.proc.pid):
            assert daemon.proc.poll() is None
        assert "first frame" not in daemon.log()  # still starting
        code, _ = terminate(daemon.proc)
        daemon.stop()
    finally:
        line.close()
    assert code == 0


def test_sighup_with_a_control_character_keeps_running(tmp_path, replay):
    """Found by the config fuzzing: this used to kill the daemon (a ReaderError escaped)."""
    config = tmp_path / "c.yaml"
    config.write_text(INVERT_X_CONFIG.format(invert="false"))
    install(replay / "stick.hid", recording([StickState(), StickState(x=0)]))
    line = CheckedLine(configured=[4])
    daemon = start(tmp_path, line.path, replay, "--config", str(config))
    try:
        line.wait_for(live(4))
        config.write_text(INVERT_X_CONFIG.format(invert="false") + "# \x01\n")
        daemon.signal(signal.SIGHUP)
        n = line.node(4).data_frames
        line.wait_for(lambda ln: ln.node(4).data_frames > n + 50 or daemon.proc.poll() is not None)
        assert daemon.proc.poll() is None, "the daemon died on SIGHUP"
    finally:
        daemon.stop()
        line.close()
