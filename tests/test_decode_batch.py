"""ReportDecoder.feed_batch: the state and counters of `feed` on every report, in order.

It decodes only the last valid report of each report ID (what a pulled reader's drain takes
in one pull), and with `on_buttons` reports the button mask after every report that
changed it (a tap inside a batch must not be lost); these tests hold it to the one-by-one
result on every real descriptor and on a device whose report IDs share buttons (where the
order of the survivors matters).
"""

from __future__ import annotations

import json
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st

from usb2rc.hid.descriptor import DeviceLayout, ReportDecoder, parse_descriptor

REAL = [
    parse_descriptor(bytes.fromhex(d["hex"]))
    for d in json.loads((Path(__file__).parent / "data" / "real-devices.json").read_text())
]
REAL = [layout for layout in REAL if layout.input_report_lengths]

# Two report IDs that both carry buttons 1-8; ID 2 also an 8-bit X.
SHARED_BUTTONS = bytes.fromhex(
    "05010904a101"
    "8501 0509 1901 2908 1500 2501 7501 9508 8102"
    "8502 0509 1901 2908 1500 2501 7501 9508 8102 0501 0930 1500 26ff00 7508 9501 8102"
    "c0".replace(" ", "")
)


def reports_for(layout: DeviceLayout) -> st.SearchStrategy[bytes]:
    """Valid reports of every ID, and short, empty and unknown-ID ones."""
    ids = sorted(layout.input_report_lengths)

    def report(rid: int, body: bytes) -> bytes:
        head = bytes([rid]) if layout.uses_report_ids else b""
        return head + body

    valid = st.sampled_from(ids).flatmap(
        lambda rid: st.binary(
            min_size=layout.input_report_lengths[rid], max_size=layout.input_report_lengths[rid]
        ).map(lambda body, rid=rid: report(rid, body))
    )
    odd = st.binary(max_size=4)  # short, empty, or an ID the device does not have
    return st.one_of(valid, valid, valid, odd)


def one_by_one(layout: DeviceLayout, reports: list[bytes]) -> tuple[object, ...]:
    """State, counters, accepted, and the button mask after each accepted report that
    changed it."""
    decoder = layout.make_decoder()
    masks = []
    accepted = 0
    for report in reports:
        before = decoder.state().buttons
        if decoder.feed(report):
            accepted += 1
            if decoder.state().buttons != before:
                masks.append(decoder.state().buttons)
    return decoder.state(), decoder.reports, decoder.bad_reports, accepted, masks


def batched(layout: DeviceLayout, batches: list[list[bytes]]) -> tuple[object, ...]:
    decoder = layout.make_decoder()
    accepted = 0
    masks: list[int] = []
    for batch in batches:
        accepted += decoder.feed_batch(batch, masks.append)[0]
    without = layout.make_decoder()  # and without on_buttons: the same state and counts
    for batch in batches:
        without.feed_batch(batch)
    assert (without.state(), without.reports, without.bad_reports) == (
        decoder.state(),
        decoder.reports,
        decoder.bad_reports,
    )
    for compiled in (True, False):  # feed_presses: the rising edges of those masks
        presser = ReportDecoder(layout, compiled=compiled)
        pressed = [p for batch in batches for p in presser.feed_presses(list(batch))[2]]
        assert pressed == rising_edges(masks)
        assert presser.state() == decoder.state()
    return decoder.state(), decoder.reports, decoder.bad_reports, accepted, masks


def rising_edges(masks: list[int]) -> list[int]:
    """The buttons each change pressed (bits up before it), for the changes that pressed."""
    before, edges = 0, []
    for mask in masks:
        if mask & ~before:
            edges.append(mask & ~before)
        before = mask
    return edges


@settings(max_examples=300, deadline=None)
@given(data=st.data(), index=st.integers(min_value=0, max_value=len(REAL) - 1))
def test_batches_match_one_by_one_on_real_devices(data: st.DataObject, index: int) -> None:
    layout = REAL[index]
    reports = data.draw(st.lists(reports_for(layout), max_size=30))
    cuts = sorted(data.draw(st.lists(st.integers(0, len(reports)), max_size=4)))
    batches = [reports[a:b] for a, b in zip([0, *cuts], [*cuts, len(reports)], strict=True)]
    assert batched(layout, batches) == one_by_one(layout, reports)


@settings(max_examples=300, deadline=None)
@given(st.lists(reports_for(parse_descriptor(SHARED_BUTTONS)), max_size=20))
def test_report_ids_that_share_buttons_end_as_the_latest_says(reports: list[bytes]) -> None:
    layout = parse_descriptor(SHARED_BUTTONS)
    assert batched(layout, [reports]) == one_by_one(layout, reports)


def test_shared_buttons_example() -> None:
    layout = parse_descriptor(SHARED_BUTTONS)
    assert layout.uses_report_ids and sorted(layout.input_report_lengths) == [1, 2]
    # ID 2 presses button 1, ID 1 releases it, ID 2 comes again with X only changed: the last
    # report of each ID survives, and ID 2's is the latest, so button 1 is pressed again.
    reports = [b"\x02\x01\x10", b"\x01\x00", b"\x02\x01\x20"]
    assert batched(layout, [reports]) == one_by_one(layout, reports)
    state = one_by_one(layout, reports)[0]
    assert state.buttons == 1 and state.values == (0x20,)  # type: ignore[attr-defined]
    # ... and when ID 1's release is the latest, the button is up; the press in between is
    # still seen by on_buttons.
    reports = [b"\x02\x01\x10", b"\x01\x00"]
    assert batched(layout, [reports]) == one_by_one(layout, reports)
    assert one_by_one(layout, reports)[0].buttons == 0  # type: ignore[attr-defined]
    assert batched(layout, [reports])[4] == [1, 0]


def test_empty_batch_changes_nothing() -> None:
    layout = REAL[0]
    decoder = layout.make_decoder()
    before = decoder.state()
    assert decoder.feed_batch([], lambda mask: None) == (0, 0)
    assert decoder.state() == before and (decoder.reports, decoder.bad_reports) == (0, 0)
