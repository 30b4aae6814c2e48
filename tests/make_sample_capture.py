"""Generate the shipped sample captures in usb2rc/data/samples/ (deterministic, no clock).

    python tests/make_sample_capture.py [OUTPUT_DIR]

c2-16b-sample.bin: a startup frame, the connect sequence of a Thrustmaster T.16000M on node 0
(vid 0x044F, pid 0xB10A, "T.16000M", "JOYSTICK"), 100 live data frames with moving axes,
buttons and hat, the disconnect, then 10 failsafe frames (axes held, buttons cleared).
sumd-sample.bin: 100 live 8-channel SUMD frames (4 axes, 4 buttons), then 10 failsafe frames.
tests/test_decode_cli.py checks the shipped files equal this script's output.
"""

from __future__ import annotations

import sys
from pathlib import Path

from usb2rc.config import layout
from usb2rc.protocols.c2_16b import codec as c2_16b
from usb2rc.protocols.sumd.codec import axis_to_sumd, button_to_sumd, encode_sumd

SAMPLES_DIR = Path(__file__).resolve().parent.parent / "usb2rc" / "data" / "samples"
C2_SAMPLE_NAME = "c2-16b-sample.bin"
SUMD_SAMPLE_NAME = "sumd-sample.bin"
SAMPLE_VERSION = "0.1.0"  # fixed, so a version bump does not change the sample
NODE_ID = 0
LIVE_FRAMES = 100
FAILSAFE_FRAMES = 10
HAT_FIRST_BIT = 24  # group 1 bits 24-31: UP, UP-RIGHT, ... UP-LEFT


def triangle(step: int, period: int, phase: int = 0) -> int:
    """An int16 triangle wave: -32768 at step 0, +32767 at half a period, integer math only."""
    position = (step + phase) % period
    half = period // 2
    rising = position if position <= half else period - position
    return -32768 + rising * 65535 // half


def sample_axes(step: int) -> list[int]:
    axes = [0] * layout.AXIS_COUNT
    axes[0] = triangle(step, 40)  # x
    axes[1] = triangle(step, 40, phase=10)  # y
    axes[2] = -32768 + step * 65535 // (LIVE_FRAMES - 1)  # z: throttle ramp, low to high
    axes[3] = triangle(step, 100, phase=50)  # slider
    axes[6] = triangle(step, 20, phase=5)  # rz: twist
    return axes


def sample_buttons(step: int) -> tuple[int, int]:
    group1 = 0
    if 20 <= step < 30:
        group1 |= 1 << 0  # button 1 (trigger)
    if 50 <= step < 60:
        group1 |= 1 << 1  # button 2
    if 60 <= step < 76:
        group1 |= 1 << (HAT_FIRST_BIT + (step - 60) // 2)  # hat round the clock
    group2 = 1 << 0 if 80 <= step < 90 else 0  # button 25
    return group1, group2


def c2_16b_sample() -> bytes:
    frames = [
        c2_16b.startup(SAMPLE_VERSION),
        c2_16b.connected(NODE_ID),
        c2_16b.vid_pid(NODE_ID, 0x044F, 0xB10A),
        c2_16b.device_string(NODE_ID, "T.16000M"),
        c2_16b.device_type(NODE_ID, "JOYSTICK"),
    ]
    for step in range(LIVE_FRAMES):
        group1, group2 = sample_buttons(step)
        frames.append(
            c2_16b.encode_data(c2_16b.LIVE, NODE_ID, step, sample_axes(step), group1, group2)
        )
    frames.append(c2_16b.disconnected(NODE_ID))
    held_axes = sample_axes(LIVE_FRAMES - 1)
    for step in range(LIVE_FRAMES, LIVE_FRAMES + FAILSAFE_FRAMES):
        frames.append(c2_16b.encode_data(c2_16b.FAILSAFE, NODE_ID, step % 256, held_axes, 0, 0))
    return b"".join(frames)


def sumd_channels(step: int) -> list[int]:
    axes = sample_axes(step)
    group1, _ = sample_buttons(step)
    sticks = [axis_to_sumd(axes[index]) for index in (2, 0, 1, 6)]  # throttle, roll, pitch, yaw
    buttons = [button_to_sumd(bool(group1 >> bit & 1)) for bit in range(4)]
    return sticks + buttons


def sumd_sample() -> bytes:
    frames = [encode_sumd(sumd_channels(step)) for step in range(LIVE_FRAMES)]
    held = sumd_channels(LIVE_FRAMES - 1)
    frames += [encode_sumd(held, failsafe=True) for _ in range(FAILSAFE_FRAMES)]
    return b"".join(frames)


def main(argv: list[str]) -> int:
    out_dir = Path(argv[0]) if argv else SAMPLES_DIR
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / C2_SAMPLE_NAME).write_bytes(c2_16b_sample())
    (out_dir / SUMD_SAMPLE_NAME).write_bytes(sumd_sample())
    print(f"wrote {out_dir / C2_SAMPLE_NAME} and {out_dir / SUMD_SAMPLE_NAME}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
