"""The SUMD output: its row in the output registry, its own config key and how it is built
(a `SumdSession` on a serial link); importing this module registers it."""

from __future__ import annotations

from usb2rc.config.output_options import Option
from usb2rc.protocols.registry import OutputProtocol, register
from usb2rc.protocols.sumd import codec
from usb2rc.protocols.sumd.channels import SumdChannels
from usb2rc.protocols.sumd.session import SumdSession
from usb2rc.wiring import BuiltOutput, OutputContext, on_serial_port

OPTIONS = {
    "extended": Option.boolean(False, "axes onto 900-2100 µs, not 1100-1900 µs"),
}


def build(context: OutputContext) -> BuiltOutput:
    out = context.config
    assert out.port
    channels = SumdChannels.of(context.mapping.sumd_channels(out), out.extended)
    session = SumdSession(out.port, channels, channels.frame_length, out.rate_hz)
    return on_serial_port(context, session)


def _frame_length(channels: int) -> int:
    return codec.frame_length(max(codec.MIN_CHANNELS, channels))


SUMD = register(
    OutputProtocol(
        "sumd",
        "Graupner HoTT SUMD: 2..32 channels",
        default_baudrate=115200,
        default_rate_hz=100,
        frame_length=_frame_length,
        decoder=codec.SumdDecoder,
        build=build,
        channels=(codec.MIN_CHANNELS, codec.MAX_CHANNELS),
        options=OPTIONS,
        aliases={
            "hott": "HoTT's serial stream is SUMD",
            "graupner": "HoTT's serial stream is SUMD",
        },
    )
)
