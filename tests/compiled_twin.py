"""Every line session's bytes over one long random journey, as one digest: run once where the
hot path is compiled and once with USB2RC_NO_MYPYC=1 (tests/test_compiled_path.py), the
two digests must be equal.

The journey is tests/test_line_sessions.py's harness (the line opens and is lost, the link
reports its state, writes are cut short or unsure, the far end sends garbage, devices come and
go, snapshots are random, then every node is live, and usb2rc stops), driven by a seeded
random generator instead of hypothesis, for every protocol (and MAVLink's MANUAL_CONTROL) on
every kind of link. What is digested: each tick's bytes,
what the session asks of the driver, its stall state, and its stats record at the end.

    python tests/compiled_twin.py [SEED] [ACTIONS]   prints the path it ran and the digest
"""

from __future__ import annotations

import hashlib
import json
import random
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).parent))

from test_line_sessions import LINKS, NODES, SOURCES, Line, heal_and_stop, run, sessions

from usb2rc import compiled_path
from usb2rc.config.mavlink import MavlinkOptions
from usb2rc.lines.session import LineSession
from usb2rc.protocols.mavlink.session import (
    MavlinkChannels,
    MavlinkEngine,
    MavlinkSession,
    heartbeat_bytes,
    max_message_bytes,
)


def manual_control() -> LineSession:
    """MAVLink's other message: its axes and buttons from the same channels."""
    tick_bytes = heartbeat_bytes() + max_message_bytes("manual_control")
    engine = MavlinkEngine(MavlinkOptions(message="manual_control"))
    channels = MavlinkChannels(SOURCES, "manual_control")
    return MavlinkSession("mavlink", channels, engine, tick_bytes, 50.0)


def factories() -> dict[str, Any]:
    return {**sessions(), "mavlink-manual": manual_control}


def action(rng: random.Random) -> tuple[str, Any]:
    """One action of the shapes tests/test_line_sessions.py's strategies draw."""
    kind = rng.choice(["tick"] * 6 + ["open", "lose", "read", "stop", "plug", "unplug", "junk"])
    if kind == "tick":
        live = [rng.random() < 0.7 for _ in range(NODES)]
        outcome = rng.choice(
            [("all", 0, 0)] * 4
            + [("cut", rng.randrange(2**16), 0), ("unsure", rng.randrange(2**16), 7)]
        )
        queued = None if rng.random() < 0.5 else rng.randrange(400)
        return "tick", (live, rng.randrange(-32768, 32768), outcome, queued, rng.random() < 0.9)
    if kind in ("plug", "unplug"):
        return kind, rng.randrange(NODES)
    if kind == "junk":
        return "garbage", rng.randbytes(rng.randrange(64))
    return kind, None


def journey(protocol: str, link: str, seed: int, count: int) -> str:
    rng = random.Random(f"{seed}/{protocol}/{link}")
    line = Line(protocol.removesuffix("-manual"), factories()[protocol](), link)
    digest = hashlib.sha256()
    for _ in range(count):
        step = action(rng)
        if step[0] == "stop" and rng.random() < 0.9:
            step = ("read", None)  # a stop ends the journey's ticks: keep it rare
        run(line, step)
        if step[0] == "tick":
            digest.update(repr((line.ticks, line.session.stalled)).encode())
            for piece in line.unread[-1:]:
                digest.update(repr(piece).encode())
    for node in range(NODES):  # every node live for the end: every protocol sends values
        line.plug(node)
    heal_and_stop(line)
    for piece in line.unread:
        digest.update(repr(piece).encode())
    stats = line.session.stats(1.0)
    digest.update(json.dumps(stats, sort_keys=True, default=repr).encode())
    return digest.hexdigest()


def main() -> None:
    seed = int(sys.argv[1]) if len(sys.argv) > 1 else 1
    count = int(sys.argv[2]) if len(sys.argv) > 2 else 400
    total = hashlib.sha256()
    for protocol in sorted(factories()):
        for link in sorted(LINKS):
            total.update(journey(protocol, link, seed, count).encode())
    path = "compiled" if compiled_path.compiled_active() else "interpreted"
    print(path, total.hexdigest())


if __name__ == "__main__":
    main()
