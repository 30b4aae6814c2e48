"""Codec speed: µs per call, the median of several timed runs of many calls each.

.venv/bin/python bench/bench_codecs.py [--runs 7] [--calls 20000]
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

from usb2rc.protocols.c2_16b import codec as c2_16b
from usb2rc.protocols.sumd.codec import SumdDecoder, encode_sumd

AXES = [-32768, 32767, 0, 1, -1, 1000, -1000, 12345, -12345, 32767]
SUMD_16 = [0x2260 + 128 * index for index in range(16)]


def microseconds_per_call(call: Callable[[], object], calls: int, runs: int) -> float:
    timings = []
    for _ in range(runs):
        start = time.perf_counter()
        for _ in range(calls):
            call()
        timings.append((time.perf_counter() - start) / calls * 1e6)
    return statistics.median(timings)


def cases() -> dict[str, Callable[[], object]]:
    data_frame = c2_16b.encode_data(c2_16b.LIVE, 1, 17, AXES, 0x01000001, 0x80000000)
    sumd_frame = encode_sumd(SUMD_16)
    c2_decoder = c2_16b.Decoder()
    sumd_decoder = SumdDecoder()
    return {
        "encode_data (C2-16B, with LF)": lambda: c2_16b.encode_data(
            c2_16b.LIVE, 1, 17, AXES, 0x01000001, 0x80000000
        ),
        "Decoder.feed (one 36-byte data frame)": lambda: c2_decoder.feed(data_frame),
        "encode_sumd (16 channels)": lambda: encode_sumd(SUMD_16),
        "SumdDecoder.feed (one 16-channel frame)": lambda: sumd_decoder.feed(sumd_frame),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--runs", type=int, default=7)
    parser.add_argument("--calls", type=int, default=20000)
    args = parser.parse_args()
    for name, call in cases().items():
        print(f"{name:42s} {microseconds_per_call(call, args.calls, args.runs):6.2f} µs")


if __name__ == "__main__":
    main()
