"""µs per input report: usb2rc's compiled ReportDecoder vs hid-tools' generic field decoding.

    .venv/bin/python bench/bench_hid_decode.py [--reports N] [--runs N]

For each real descriptor in tests/data/real-devices.json: random reports for every input report
ID; usb2rc = `feed(report)` + `state()`; hid-tools = find the report by ID and `get_values()`
of each of its fields (what its `format_report` does before formatting). Median of several
runs. hid-tools (GPL-2.0) is a test/bench-only dependency, never imported by usb2rc itself.
"""

from __future__ import annotations

import argparse
import json
import random
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import hidtools.hid

from usb2rc.hid.descriptor import parse_descriptor

DATA = Path(__file__).resolve().parent.parent / "tests" / "data" / "real-devices.json"


def _reports(descriptor: bytes, count: int, rng: random.Random) -> list[bytes]:
    layout = parse_descriptor(descriptor)
    out = []
    ids = sorted(layout.input_report_lengths)
    for _ in range(count):
        rid = rng.choice(ids)
        body = rng.randbytes(layout.input_report_lengths[rid])
        out.append((bytes([rid]) if layout.uses_report_ids else b"") + body)
    return out


def _time_per_report(fn: Callable[[bytes], object], reports: list[bytes], runs: int) -> float:
    samples = []
    for _ in range(runs):
        start = time.perf_counter()
        for report in reports:
            fn(report)
        samples.append((time.perf_counter() - start) / len(reports) * 1e6)
    return statistics.median(samples)


def _usb2rc(descriptor: bytes) -> tuple[Callable[[bytes], object], Callable[[bytes], object]]:
    decoder = parse_descriptor(descriptor).make_decoder()
    feed, state = decoder.feed, decoder.state

    def feed_and_state(report: bytes) -> object:
        feed(report)
        return state()

    return feed, feed_and_state


def _hidtools(descriptor: bytes) -> Callable[[bytes], object]:
    rdesc = hidtools.hid.ReportDescriptor.from_bytes(list(descriptor))
    numbered = any(rid >= 0 for rid in rdesc.input_reports)

    def decode(report: bytes) -> object:
        data = list(report)
        hid_report = rdesc.get(data[0] if numbered else -1, len(data))
        assert hid_report is not None, "a report the descriptor does not describe"
        return [f.get_values(data) for f in hid_report.fields]

    return decode


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reports", type=int, default=2000)
    parser.add_argument("--runs", type=int, default=7)
    args = parser.parse_args()
    rows = []
    for device in json.loads(DATA.read_text()):
        descriptor = bytes.fromhex(device["hex"])
        reports = _reports(descriptor, args.reports, random.Random(device["name"]))
        feed, feed_state = _usb2rc(descriptor)
        ours = _time_per_report(feed, reports, args.runs)
        ours_state = _time_per_report(feed_state, reports, args.runs)
        theirs = _time_per_report(_hidtools(descriptor), reports[: args.reports // 10], args.runs)
        name = device["name"].split("(")[0].strip()[:34]
        rows.append(
            {
                "device": name,
                "fields": len(parse_descriptor(descriptor).inputs),
                "usb2rc_feed_us": round(ours, 3),
                "usb2rc_feed_state_us": round(ours_state, 3),
                "hidtools_us": round(theirs, 2),
                "speedup": round(theirs / ours_state, 1),
            }
        )
    print(f"{'device':34} {'fields':>6} {'feed µs':>8} {'+state':>8} {'hid-tools':>10} {'x':>6}")
    for r in rows:
        print(
            f"{r['device']:34} {r['fields']:6} {r['usb2rc_feed_us']:8.3f} "
            f"{r['usb2rc_feed_state_us']:8.3f} {r['hidtools_us']:10.2f} {r['speedup']:6.1f}"
        )
    print(json.dumps({"bench": "hid_decode", "unit": "us_per_report", "rows": rows}))


if __name__ == "__main__":
    main()
