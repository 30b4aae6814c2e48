"""Soak: devices plugging and unplugging every 200 ms for USB2RC_SOAK_SECONDS (default 600).

USB2RC_SOAK_DEVICES replayed sticks (default 5) take turns: every USB2RC_SOAK_STEP_MS (200)
one of them is plugged or unplugged, so each device changes state every devices × step. At
the end:

- every plug gave exactly one connect sequence (1,6,5,7) and every unplug exactly one `2`;
- message codes are consecutive for every node over the whole run (rolling over hundreds of
  times in all), nothing skipped or invented on the line;
- the daemon's threads, open fds and RSS, sampled with every device unplugged at the start
  and at the end, are flat (fds and threads equal, RSS within a generous margin).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest
from daemon_harness import DaemonProcess, StickState, install, recording
from stress_harness import CheckedLine, env_int, figures, proc_stats, terminate

from usb2rc.protocols.c2_16b import codec as c2_16b

pytestmark = pytest.mark.slow


def _settled_unplugged(line: CheckedLine, devices: int) -> bool:
    return all(
        line.node(n).status == c2_16b.FAILSAFE and line.node(n).names()[-1] == "disconnected"
        for n in range(devices)
    )


def test_soak_plug_unplug(request, tmp_path: Path):
    seconds = env_int("USB2RC_SOAK_SECONDS", 600)
    devices = env_int("USB2RC_SOAK_DEVICES", 5)
    step = env_int("USB2RC_SOAK_STEP_MS", 200) / 1000
    replay = tmp_path / "replay"
    replay.mkdir()
    texts = [
        recording(
            [StickState(), *[StickState(x=1000 * i + j, buttons=1 << i) for j in range(20)]],
            hold_s=0.01,
            name=f"Soak T.16000M {i}",
        )
        for i in range(devices)
    ]
    line = CheckedLine()
    daemon = DaemonProcess(["--port", line.path, "--replay", str(replay)], tmp_path / "d.log")
    plugs = [0] * devices
    unplugs = [0] * devices
    samples = []
    try:
        # warm up: every device once in and out, so the node IDs exist and imports are done
        for i in range(devices):
            install(replay / f"s{i}.hid", texts[i])
            plugs[i] += 1
        line.wait_for(lambda ln: all(ln.node(n).connect_sequences for n in range(devices)))
        for i in range(devices):
            os.unlink(replay / f"s{i}.hid")
            unplugs[i] += 1
        line.wait_for(lambda ln: _settled_unplugged(ln, devices))
        time.sleep(1)
        start = proc_stats(daemon.proc.pid)
        t0 = time.monotonic()
        k = 0
        next_at = time.monotonic()
        while time.monotonic() - t0 < seconds:
            i = k % devices
            path = replay / f"s{i}.hid"
            if path.exists():
                os.unlink(path)
                unplugs[i] += 1
            else:
                install(path, texts[i])
                plugs[i] += 1
            k += 1
            if k % 500 == 0:
                samples.append((round(time.monotonic() - t0), proc_stats(daemon.proc.pid)))
            next_at += step
            time.sleep(max(0.0, next_at - time.monotonic()))
        for i in range(devices):  # end with every device unplugged, as at the start
            path = replay / f"s{i}.hid"
            if path.exists():
                time.sleep(step)
                os.unlink(path)
                unplugs[i] += 1
        line.wait_for(lambda ln: _settled_unplugged(ln, devices), timeout=30)
        line.wait_for(
            lambda ln: all(
                ln.node(n).names().count("disconnected") >= unplugs[n] for n in range(devices)
            ),
            timeout=30,
        )
        time.sleep(1)
        end = proc_stats(daemon.proc.pid)
        with line.locked():
            connects = [line.node(n).connect_sequences for n in range(devices)]
            disconnects = [line.node(n).names().count("disconnected") for n in range(devices)]
            errors = [line.node(n).names().count("error") for n in range(devices)]
        line.assert_clean()
        rollovers = line.rollovers()
        data_frames = line.data_frames_total()
        code, _ = terminate(daemon.proc)
    finally:
        daemon.stop()
        line.close()
    log = daemon.log()
    assert code == 0 and "Traceback" not in log
    figures(
        request,
        "soak",
        {
            "seconds": seconds,
            "devices": devices,
            "plugs": sum(plugs),
            "unplugs": sum(unplugs),
            "connect_sequences": sum(connects),
            "disconnects": sum(disconnects),
            "data_frames": data_frames,
            "code_rollovers": rollovers,
            "start": start.as_dict(),
            "end": end.as_dict(),
            "rss_samples_kb": [s.rss_kb for _, s in samples],
        },
    )
    assert connects == plugs, (connects, plugs)
    assert disconnects == unplugs, (disconnects, unplugs)
    assert errors == [0] * devices
    assert end.fds == start.fds, (start, end)
    assert end.threads == start.threads, (start, end)
    assert end.rss_kb - start.rss_kb < max(8 * 1024, start.rss_kb // 4), (start, end)
