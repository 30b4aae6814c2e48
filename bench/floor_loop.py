"""The floor of the drivers' loop in Python: bench/floor_loop.c's loop, line for line, with
the same arguments (bench/bench_floor.py runs both). Not usb2rc's code: what the
interpreter costs for the loop's bare shape (sleeps to deadlines, a read per report, a
frame and a write per tick)."""

from __future__ import annotations

import binascii
import os
import signal
import sys
import time
from typing import Any

stopping = False


def on_term(_sig: int, _frame: object) -> None:
    global stopping
    stopping = True


def main(argv: list[str]) -> int:
    lead = int(argv[1]) / 1e6
    devs: list[int] = []
    outs: list[list[Any]] = []  # [fd, period, len, deadline, held, frame]
    args = iter(argv[2:])
    for arg in args:
        if arg == "--dev":
            devs.append(int(next(args)))
        elif arg == "--out":
            outs.append([int(next(args)), int(next(args)) / 1e6, int(next(args)), 0.0, False, b""])
        else:
            return 2
    signal.signal(signal.SIGTERM, on_term)
    state = b"\0"
    t0 = time.monotonic()
    for o in outs:
        o[3] = (int(t0 / o[1]) + 1) * o[1]
    while not stopping:
        moment = min(o[3] if o[4] else o[3] - lead for o in outs)
        delay = moment - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        now = time.monotonic()
        wrote = False
        for o in outs:
            if o[4] and o[3] <= now:
                try:  # noqa: SIM105 - the floor: no context manager on the hot path
                    os.write(o[0], o[5])
                except BlockingIOError:
                    pass
                o[4] = False
                o[3] += o[1]
                while o[3] - lead <= time.monotonic():  # missed: skipped
                    o[3] += o[1]
                wrote = True
        if wrote:
            continue
        for d in devs:  # the pull: a read per report, as hidraw
            while True:
                try:
                    state = os.read(d, 256)
                except BlockingIOError:
                    break
        for o in outs:
            if not o[4] and o[3] - lead <= now + 0.0002:
                body = (state * (o[2] // len(state) + 1))[: o[2] - 2]
                o[5] = body + binascii.crc_hqx(body, 0).to_bytes(2, "big")
                o[4] = True
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
