"""Fuzzing the report-descriptor parser with the shared real descriptors, mutated.

Every mutation must give either a DeviceLayout whose decoder takes reports of every length
and ID without raising, or a DescriptorError with a message; never another exception and
never a hang (each parse runs under a 2 s alarm). `-m slow` runs
USB2RC_FUZZ_DESCRIPTOR_MUTATIONS mutations per real device (default 1000: 13 000 in all), and
puts a set of mutated descriptors in front of the running daemon: one clear error per
unusable device, the usable ones connected, the good stick live throughout.
"""

from __future__ import annotations

import json
import random
import signal
import time
from pathlib import Path

import pytest
from daemon_harness import DaemonProcess, StickState, install, recording
from stress_harness import CheckedLine, env_int, figures, mutate, terminate

from usb2rc.hid.descriptor import DescriptorError, DeviceLayout, parse_descriptor
from usb2rc.hid.replay import ReplayBackend

DEVICES = {
    d["name"]: bytes.fromhex(d["hex"])
    for d in json.loads((Path(__file__).parent / "data" / "real-devices.json").read_text())
}
HANG_S = 2.0


class Hang(Exception):
    pass


def _alarm(_signum, _frame):
    raise Hang()


def _representable(bits: int, signed: bool) -> tuple[int, int]:
    """What a field can hold; a 1-bit field is read unsigned (as descriptor.py does)."""
    if signed and bits > 1:
        return -(1 << (bits - 1)), (1 << (bits - 1)) - 1
    return 0, (1 << bits) - 1


def exercise(layout: DeviceLayout, rng: random.Random) -> dict[str, int]:
    """Reports of the right length, short, long, empty and with unknown IDs."""
    decoder = layout.make_decoder()
    bad = good = 0
    for rid, length in layout.input_report_lengths.items():
        prefix = bytes([rid]) if layout.uses_report_ids else b""
        for extra in (0, 1, 7):
            assert decoder.feed(prefix + rng.randbytes(length + extra)), "a long report is valid"
            good += 1
        if length + len(prefix) > 0:
            assert not decoder.feed((prefix + rng.randbytes(length))[:-1]), "short report taken"
            bad += 1
    assert not decoder.feed(b"") or (
        not layout.uses_report_ids and min(layout.input_report_lengths.values()) == 0
    )
    if layout.uses_report_ids:
        unknown = [i for i in range(256) if i not in layout.input_report_lengths]
        if unknown:
            rid = rng.choice(unknown)
            assert not decoder.feed(bytes([rid]) + rng.randbytes(64)), "unknown ID taken"
            bad += 1
    state = decoder.state()
    assert len(state.values) == len(layout.inputs)
    assert state.buttons >= 0 and state.buttons >> max(layout.button_count, 0) == 0
    for field, value in zip(layout.inputs, state.values, strict=True):
        lo, hi = _representable(field.bit_size, field.is_signed)
        assert lo <= value <= hi, (field, value)
    assert decoder.bad_reports >= bad
    return {"good": good, "bad": bad}


def check(data: bytes, rng: random.Random, tally: dict[str, int]) -> None:
    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, HANG_S)
    try:
        layout = parse_descriptor(data)
        counts = exercise(layout, rng)
    except DescriptorError as exc:
        assert str(exc).strip(), "a DescriptorError without a message"
        tally["descriptor_errors"] += 1
        return
    except Hang:
        pytest.fail(f"parse or decode took over {HANG_S} s: {data.hex()}")
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    tally["layouts"] += 1
    tally["reports_fed"] += counts["good"] + counts["bad"]


def run(per_device: int, seed: int) -> dict[str, int]:
    rng = random.Random(seed)
    tally = {"mutations": 0, "layouts": 0, "descriptor_errors": 0, "reports_fed": 0}
    for name, descriptor in sorted(DEVICES.items()):
        for _ in range(per_device):
            data = mutate(descriptor, rng, max_ops=rng.choice((1, 2, 4, 12)))
            tally["mutations"] += 1
            try:
                check(data, rng, tally)
            except AssertionError as exc:
                raise AssertionError(f"{name} mutated to {data.hex()}: {exc}") from exc
    return tally


def test_real_descriptors_parse():
    for name, descriptor in DEVICES.items():
        layout = parse_descriptor(descriptor)
        assert layout.inputs or layout.button_count, name
        exercise(layout, random.Random(name))


def test_mutated_descriptors_fast():
    tally = run(40, 1)
    assert tally["layouts"] and tally["descriptor_errors"]


@pytest.mark.slow
def test_mutated_descriptors_long(request):
    per_device = env_int("USB2RC_FUZZ_DESCRIPTOR_MUTATIONS", 1000)
    t0 = time.monotonic()
    tally = run(per_device, env_int("USB2RC_FUZZ_SEED", 20240601))
    tally["seconds"] = round(time.monotonic() - t0, 1)  # type: ignore[assignment]
    tally["devices"] = len(DEVICES)
    figures(request, "fuzz-descriptor", tally)
    assert tally["mutations"] >= 10_000 or per_device < 1000


def _replay_text(descriptor: bytes, name: str, vid: int) -> str:
    lines = [
        f"R: {len(descriptor)} " + " ".join(f"{b:02x}" for b in descriptor),
        f"N: {name}",
        f"I: 3 {vid:04x} 0001",
        "E: 0.000000 8 00 00 00 00 00 00 00 00",
    ]
    return "\n".join(lines) + "\n"


@pytest.mark.slow
def test_daemon_with_mutated_descriptors(request, tmp_path):
    """Mutated descriptors as plugged devices: each one usable or one clear error, no crash."""
    replay = tmp_path / "replay"
    replay.mkdir()
    install(replay / "a-stick.hid", recording([StickState(x=0)]))
    rng = random.Random(5)
    seeds = sorted(DEVICES.items())
    count = env_int("USB2RC_FUZZ_DAEMON_DESCRIPTORS", 24)
    for i in range(count):
        _, descriptor = seeds[i % len(seeds)]
        data = mutate(descriptor, rng, max_ops=3)
        install(replay / f"m{i:02d}.hid", _replay_text(data, f"Mutant{i:02d}", 0x1000 + i))
    backend = ReplayBackend(replay)
    infos = backend.enumerate()  # the others are not joysticks: never plugged
    usable = len(infos)
    broken = 0
    for info in infos:
        try:
            parse_descriptor(backend.open(info).report_descriptor())
        except DescriptorError:
            broken += 1
    line = CheckedLine()
    daemon = DaemonProcess(["--port", line.path, "--replay", str(replay)], tmp_path / "d.log")
    try:
        # every device is either connected or reported in error, the stick stays live
        def settled(ln: CheckedLine) -> bool:  # errors may reuse a node ID: count frames
            connects = sum(log.connect_sequences for log in ln.nodes.values())
            errors = sum(log.names().count("error") for log in ln.nodes.values())
            return connects + errors >= usable and ln.node(0).data_frames > 50

        line.wait_for(settled, timeout=60)
        errors = sum(log.names().count("error") for log in line.nodes.values())
        code, _ = terminate(daemon.proc)
    finally:
        daemon.stop()
        line.close()
    log = daemon.log()
    assert code == 0
    assert "Traceback" not in log
    assert errors >= broken
    unusable = [ln for ln in log.splitlines() if "not used:" in ln]
    assert len(unusable) == errors, unusable
    assert all("Mutant" in ln for ln in unusable)
    line.assert_clean()
    figures(
        request,
        "fuzz-descriptor-daemon",
        {
            "devices": count,
            "joystick_like": usable - 1,
            "unparsable": broken,
            "error_frames": errors,
            "stick_live": True,
        },
    )
