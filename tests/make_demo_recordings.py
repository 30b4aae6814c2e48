"""Generate usb2rc/data/demo/{stick,throttle}.hid: ~20 s at 100 reports/s of plausible input.

    python tests/make_demo_recordings.py          # rewrite the shipped files
    python tests/make_demo_recordings.py --check  # exit 1 if they differ

Reports are packed by hand from the field layout of each device's real report descriptor
(tests/data/real-devices.json), not by usb2rc's own parser, so the demo files
also test that parser (tests/test_demo_recordings.py decodes them).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

from usb2rc.hid.recording import RecordedEvent, Recording, format_recording

DEMO_DIR = Path(__file__).resolve().parent.parent / "usb2rc" / "data" / "demo"
RATE_HZ = 100
SECONDS = 20
HAT_NULL = 0x0F  # outside 0..7: centred

T16000M_DESCRIPTOR = bytes.fromhex(
    "05010904a101050919012910150025013500450175019510810205010939150025073500463b016514750495"
    "01814281010930150026ff3f350046ff3f6500750e950181027502950181010931750e950181027502950181"
    "0109350936150026ff00350046ff0065007508950281027508953781010600ff27ffff0000090175089504b1"
    "a2c0"
)
TWCS_DESCRIPTOR = bytes.fromhex(
    "05010904a10185010930093109350933093409360937150026ff037510950781020932150027ffff00007510"
    "950181020939150025073500463b016514750495018142650005091901290e150025017501950e8102750695"
    "0181010600ff09217508952c810206f0ff094085f109477508953fb102c0"
)

# Field layouts read off the descriptors above: name -> (bit offset, bit size).
# T.16000M, no report ID, 64 data bytes.
STICK_FIELDS = {
    "buttons": (0, 16),
    "hat": (16, 4),
    "x": (24, 14),
    "y": (40, 14),
    "rz": (56, 8),
    "slider": (64, 8),
}
STICK_LENGTH = 64
# TWCS, report ID 1, 63 data bytes after the ID byte.
THROTTLE_FIELDS = {
    "x": (0, 16),
    "y": (16, 16),
    "rz": (32, 16),
    "rx": (48, 16),
    "ry": (64, 16),
    "slider": (80, 16),
    "dial": (96, 16),
    "z": (112, 16),
    "hat": (128, 4),
    "buttons": (132, 14),
}
THROTTLE_LENGTH = 63
THROTTLE_REPORT_ID = 1


def pack(fields: dict[str, tuple[int, int]], values: dict[str, int], length: int) -> bytes:
    """Little-endian bit packing, HID style: bit n of the report is bit n%8 of byte n//8."""
    word = 0
    for name, value in values.items():
        offset, size = fields[name]
        if not 0 <= value < (1 << size):
            raise ValueError(f"{name}={value} does not fit {size} bits")
        word |= value << offset
    return word.to_bytes(length, "little")


def wave(t: float, period: float, lo: int, hi: int, phase: float = 0.0, gain: float = 1.0) -> int:
    """A sine from lo to hi (scaled by gain) around the centre."""
    centre, amp = (lo + hi) / 2, gain * (hi - lo) / 2
    return round(centre + amp * math.sin(2 * math.pi * (t / period + phase)))


def triangle(t: float, period: float, lo: int, hi: int) -> int:
    """lo -> hi -> lo over one period."""
    x = (t / period) % 1.0
    return round(lo + (hi - lo) * (2 * x if x < 0.5 else 2 - 2 * x))


def one_button(t: float, count: int, start: float, step: float) -> int:
    """Buttons 1..count pressed one after another, each for 60% of `step`."""
    k, frac = divmod(t - start, step)
    if t < start or k >= count or frac >= 0.6 * step:
        return 0
    return 1 << int(k)


def hat_round(t: float, start: float, step: float) -> int:
    """Centred, then UP, UP-RIGHT ... UP-LEFT, each held for `step`, centred between laps."""
    if t < start:
        return HAT_NULL
    k = int((t - start) // step) % 9
    return k if k < 8 else HAT_NULL


REST_LEAD_S = 0.5  # both devices hold their t=0 values (at rest) first: the neutral guard's rest


def stick_values(t: float) -> dict[str, int]:
    t = max(0.0, t - REST_LEAD_S)
    if t < 10:  # circles on X/Y, growing from the centre over the first 2 s
        gain = min(1.0, t / 2.0)
        x = wave(t, 4.0, 0, 16383, gain=gain)
        y = wave(t, 4.0, 0, 16383, phase=0.25, gain=gain)
    else:  # full sweeps: X fast, Y slow, both starting from the centre
        x = triangle(t - 10 + 0.625, 2.5, 0, 16383)
        y = triangle(t - 10 + 2.5, 10.0, 0, 16383)
    return {
        "x": x,
        "y": y,
        "rz": wave(t, 5.0, 0, 255),
        "slider": triangle(t, SECONDS, 0, 255),
        "buttons": one_button(t, 16, 1.0, 1.0),
        "hat": hat_round(t, 2.0, 0.5),
    }


def throttle_values(t: float) -> dict[str, int]:
    t = max(0.0, t - REST_LEAD_S)
    return {
        "z": triangle(t, 10.0, 0, 65535),
        "x": wave(t, 3.0, 0, 1023),
        "y": wave(t, 3.0, 0, 1023, phase=0.5),
        "rz": wave(t, 6.0, 0, 1023),
        "rx": 512,
        "ry": 512,
        "slider": triangle(t, 8.0, 0, 1023),
        "dial": wave(t, 20.0, 0, 1023),
        "buttons": one_button(t, 14, 1.5, 1.2),
        "hat": hat_round(t, 3.0, 0.4),
    }


def events(make: Callable[[float], bytes]) -> Iterator[RecordedEvent]:
    for i in range(SECONDS * RATE_HZ):
        t = i / RATE_HZ
        yield RecordedEvent(round(t, 6), make(t))


def stick_report(t: float) -> bytes:
    return pack(STICK_FIELDS, stick_values(t), STICK_LENGTH)


def throttle_report(t: float) -> bytes:
    data = pack(THROTTLE_FIELDS, throttle_values(t), THROTTLE_LENGTH)
    return bytes([THROTTLE_REPORT_ID]) + data


HEADER = (
    "# usb2rc demo recording ({what}); generated by tests/make_demo_recordings.py, do not edit\n"
)


def demo_files() -> dict[str, str]:
    stick = Recording(
        T16000M_DESCRIPTOR,
        "Thrustmaster T.16000M",
        "usb-0000:00:14.0-1.2/input0",
        3,
        0x044F,
        0xB10A,
        tuple(events(stick_report)),
    )
    throttle = Recording(
        TWCS_DESCRIPTOR,
        "Thrustmaster TWCS Throttle",
        "usb-0000:00:14.0-1.3/input0",
        3,
        0x044F,
        0xB687,
        tuple(events(throttle_report)),
    )
    return {
        "stick.hid": HEADER.format(what="stick circles, sweeps, twist, buttons, hat")
        + format_recording(stick),
        "throttle.hid": HEADER.format(what="throttle ramps, mini-stick, rocker, buttons, hat")
        + format_recording(throttle),
    }


def main(argv: list[str]) -> int:
    check = "--check" in argv
    stale = []
    for name, text in demo_files().items():
        path = DEMO_DIR / name
        if check:
            if not path.exists() or path.read_text(encoding="utf-8") != text:
                stale.append(name)
        else:
            DEMO_DIR.mkdir(parents=True, exist_ok=True)
            path.write_text(text, encoding="utf-8")
    if stale:
        print(f"stale demo recordings: {', '.join(stale)}; run {argv[0]}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv))
