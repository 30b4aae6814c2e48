"""usb2rc's descriptor parser and decoder against hid-tools (an independent implementation) on
the report descriptors of 13 real devices."""

from __future__ import annotations

import json
import random
from pathlib import Path

import hid_encoder
import pytest

from usb2rc.hid.descriptor import DeviceLayout, parse_descriptor

DEVICES = json.loads((Path(__file__).parent / "data" / "real-devices.json").read_text())
REPORTS_PER_DESCRIPTOR = 400


def _ids(device: dict) -> str:
    return device["name"].split("(")[0].strip()


def _my_keys(layout: DeviceLayout) -> dict[int, dict[hid_encoder.ValueKey, int]]:
    """report ID -> (usage, k-th in this report) -> index in layout.inputs."""
    keys: dict[int, dict[hid_encoder.ValueKey, int]] = {}
    for f in layout.inputs:
        per_report = keys.setdefault(f.report_id, {})
        k = sum(1 for usage, _ in per_report if usage == f.usage)
        per_report[(f.usage, k)] = f.index
    return keys


@pytest.fixture(params=DEVICES, ids=_ids)
def device(request: pytest.FixtureRequest) -> dict:
    return request.param


def test_layout_matches_hidtools_fields(device: dict) -> None:
    descriptor = bytes.fromhex(device["hex"])
    layout = parse_descriptor(descriptor)
    refs = hid_encoder.ref_reports(descriptor)
    my_keys = _my_keys(layout)
    assert set(layout.input_report_lengths) == set(refs)
    for rid, ref in refs.items():
        assert layout.input_report_lengths[rid] == ref.size - (1 if ref.numbered else 0)
        assert layout.uses_report_ids == ref.numbered
        assert set(my_keys.get(rid, {})) == set(ref.values)
        for key, index in my_keys.get(rid, {}).items():
            mine, theirs = layout.inputs[index], ref.values[key]
            id_bits = 8 if ref.numbered else 0
            assert mine.bit_offset + id_bits == theirs.start
            assert mine.bit_size == theirs.size
            assert mine.logical_min == theirs.logical_min
            assert mine.logical_max == theirs.logical_max


def test_random_reports_decode_like_hidtools(device: dict) -> None:
    descriptor = bytes.fromhex(device["hex"])
    layout = parse_descriptor(descriptor)
    refs = hid_encoder.ref_reports(descriptor)
    my_keys = _my_keys(layout)
    decoder = layout.make_decoder()
    rng = random.Random(device["name"])
    expected_values = list(layout.initial_state().values)
    expected_buttons: dict[int, set[int]] = {}
    for _ in range(REPORTS_PER_DESCRIPTOR):
        rid = rng.choice(sorted(refs))
        ref = refs[rid]
        report = bytearray(rng.randbytes(ref.size + rng.choice((0, 0, 0, 3))))
        if ref.numbered:
            report[0] = rid
        assert decoder.feed(bytes(report))
        values, pressed = hid_encoder.decode(ref, bytes(report))
        for key, value in values.items():
            expected_values[my_keys[rid][key]] = value
        expected_buttons[rid] = pressed
        state = decoder.state()
        assert state.values == tuple(expected_values)
        assert _bits(state.buttons) == set().union(*expected_buttons.values())
    assert decoder.bad_reports == 0


def test_encoded_values_round_trip(device: dict) -> None:
    descriptor = bytes.fromhex(device["hex"])
    layout = parse_descriptor(descriptor)
    refs = hid_encoder.ref_reports(descriptor)
    my_keys = _my_keys(layout)
    rng = random.Random(device["name"] + "encode")
    for _ in range(REPORTS_PER_DESCRIPTOR // 4):
        rid = rng.choice(sorted(refs))
        ref = refs[rid]
        values = hid_encoder.random_values(ref, rng)
        buttons = {n for n in ref.buttons if rng.random() < 0.5}
        decoder = layout.make_decoder()
        assert decoder.feed(hid_encoder.encode(ref, values, buttons))
        state = decoder.state()
        for key, value in values.items():
            assert state.values[my_keys[rid][key]] == value
        assert _bits(state.buttons) == buttons


def test_short_and_unknown_reports_are_refused(device: dict) -> None:
    layout = parse_descriptor(bytes.fromhex(device["hex"]))
    decoder = layout.make_decoder()
    before = decoder.state()
    for rid, length in layout.input_report_lengths.items():
        prefix = bytes([rid]) if layout.uses_report_ids else b""
        assert not decoder.feed(prefix + bytes(length - 1))
    assert not decoder.feed(b"")
    if layout.uses_report_ids:
        unknown = next(i for i in range(1, 256) if i not in layout.input_report_lengths)
        assert not decoder.feed(bytes([unknown]) + bytes(64))
    assert decoder.state() == before
    assert decoder.bad_reports == len(layout.input_report_lengths) + 1 + layout.uses_report_ids


def _bits(mask: int) -> set[int]:
    return {i + 1 for i in range(mask.bit_length()) if mask >> i & 1}
