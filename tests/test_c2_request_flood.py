"""Far-end request floods on a C2-16B line (issue 19 point 8), black-box: the daemon as a
subprocess, the far end on a real pty.

Before, each `<` cost every node 1-3 `!` frames (a `<` every 20 ms left 26 % `>`; `4` for all
255 nodes every 20 ms left 1-2 % `>`). Now a node announced on the line stays `>` while it
is announced again (docs/ICD.md, "Sequences"), and the requests are read at most at twice the
line's rate and wait coalesced, one answer per node (docs/ICD.md, "UART receive").
"""

from __future__ import annotations

import json
import os
import select
import signal
import threading
import time
from pathlib import Path

from daemon_harness import (
    PtyLine,
    StickState,
    data_frames,
    install,
    recording,
    run_daemon,
    services,
)

from usb2rc.protocols.c2_16b import codec as c2_16b

WAIT_S = 30.0
NODES = (0, 1)
ROUND = c2_16b.encode_data(c2_16b.CONFIG_REQUEST, 0x10, 0, [0] * 10, 0, 0) + b"".join(
    c2_16b.poll_request(node) for node in range(256)
)  # a `<` and a `4` for every Node-ID: 257 requests


def json_stats(text: str) -> list[dict]:
    return [json.loads(line)["stats"] for line in text.splitlines() if line.startswith('{"stats"')]


def answered_twice_live(frames: list[object], since: int) -> bool:
    """Each node announced again twice since `since`, with 50 data frames meanwhile."""
    after = frames[since:]
    return all(
        services(after, node).count("device-type") >= 2 and len(data_frames(after, node)) >= 50
        for node in NODES
    )


def test_a_request_flood_never_costs_a_live_node_its_live_frames(tmp_path: Path, replay_dir):
    line = PtyLine()
    for node in NODES:
        install(replay_dir / f"s{node}.hid", recording([StickState(), StickState(x=100 * node)]))
    path = tmp_path / "c2.yaml"
    path.write_text(
        f"outputs:\n  - {{protocol: c2-16b, port: {line.path}}}\n"
        "devices:\n"
        "  - {name: a, match: {port: replay-s0}, node_id: 0}\n"
        "  - {name: b, match: {port: replay-s1}, node_id: 1}\n"
    )
    daemon = run_daemon(
        tmp_path, line.path, replay_dir, "--config", str(path), "--stats-format", "json"
    )
    stop = threading.Event()

    def flood() -> None:  # as fast as the daemon's side takes the bytes, until stopped
        data = ROUND
        while not stop.is_set():
            select.select([], [line.master], [], 0.05)
            try:
                data = data[os.write(line.master, data) :] or ROUND
            except BlockingIOError:
                continue

    try:
        for node in NODES:
            line.wait_for(lambda fr, n=node: [f.status for f in data_frames(fr, n)[-1:]] == [62])
        since = len(line.frames())
        os.set_blocking(line.master, False)  # the reader selects first; the writer must stop
        writer = threading.Thread(target=flood)
        writer.start()
        try:
            line.wait_for(lambda fr: answered_twice_live(fr, since), WAIT_S)
        finally:
            stop.set()
            writer.join(WAIT_S)
        daemon.signal(signal.SIGUSR1)
        deadline = time.monotonic() + WAIT_S
        while not (records := json_stats(daemon.log())):
            assert time.monotonic() < deadline, daemon.log()[-3000:]
            time.sleep(0.05)
        flooded = data_frames(line.frames()[since:])  # (a stop sends `!`: docs/ICD.md, Stop)
    finally:
        daemon.stop()
        line.close()
    statuses = {chr(f.status) for f in flooded if f.node_id in NODES}
    assert statuses == {">"}, f"{len(flooded)} data frames: {statuses}"
    (c2,) = records[-1]["outputs"]
    assert c2["rx_requests"] > 0 and c2["rx_dropped_bytes"] > 0  # read at the line's rate
