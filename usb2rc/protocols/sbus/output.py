"""The SBUS output: its row in the output registry and how it is built (an `SbusSession` on
a serial link, 8E2); importing this module registers it."""

from __future__ import annotations

from usb2rc.protocols.channels import OutputChannels
from usb2rc.protocols.rc11_channels import RC11_SCALE
from usb2rc.protocols.registry import OutputProtocol, fixed_length, register
from usb2rc.protocols.sbus import codec
from usb2rc.protocols.sbus.session import SbusSession
from usb2rc.wiring import BuiltOutput, OutputContext, on_serial_port


def build(context: OutputContext) -> BuiltOutput:
    import serial  # pyserial: only when an output is built

    out = context.config
    assert out.port
    sources = context.mapping.sumd_channels(out)
    session = SbusSession(
        out.port, OutputChannels.scaled(sources, RC11_SCALE, codec.FRAME_LEN), out.rate_hz
    )
    return on_serial_port(context, session, parity=serial.PARITY_EVEN, stopbits=serial.STOPBITS_TWO)


SBUS = register(
    OutputProtocol(
        "sbus",
        "Futaba SBUS: 16 channels, ch17/ch18, frame-lost and failsafe flags (8E2)",
        default_baudrate=codec.BAUDRATE,
        default_rate_hz=100,
        frame_length=fixed_length(codec.FRAME_LEN),
        decoder=codec.SbusDecoder,
        build=build,
        bits_per_byte=codec.BITS_PER_BYTE,
        channels=(1, 18),
        channels_required=True,
        note="8E2, axes 172..1811, frame-lost + failsafe flags while failsafe",
        aliases={"futaba": "Futaba's serial stream is SBUS"},
    )
)
