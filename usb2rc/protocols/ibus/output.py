"""The iBus output: its channels' scale, its row in the output registry and how it is built
(an `IbusSession` on a serial link); importing this module registers it."""

from __future__ import annotations

from usb2rc.protocols.channels import OutputChannels, WireScale
from usb2rc.protocols.ibus import codec
from usb2rc.protocols.ibus.session import IbusSession
from usb2rc.protocols.registry import OutputProtocol, fixed_length, register
from usb2rc.wiring import BuiltOutput, OutputContext, on_serial_port

IBUS_SCALE = WireScale(codec.axis_to_ibus, codec.button_to_ibus)  # 1000..2000 µs, centre 1500


def build(context: OutputContext) -> BuiltOutput:
    out = context.config
    assert out.port
    sources = context.mapping.sumd_channels(out)
    session = IbusSession(
        out.port, OutputChannels.scaled(sources, IBUS_SCALE, codec.FRAME_LEN), out.rate_hz
    )
    return on_serial_port(context, session)


IBUS = register(
    OutputProtocol(
        "ibus",
        "FlySky iBus: 14 channels 1000..2000 µs, silent while failsafe",
        default_baudrate=codec.BAUDRATE,
        # 100 Hz as SUMD and SBUS: FlySky receivers send every 7 ms but flight controllers
        # take any rate, and 32 bytes at 115200 baud fit up to 360 Hz.
        default_rate_hz=100,
        frame_length=fixed_length(codec.FRAME_LEN),
        decoder=codec.IbusDecoder,
        build=build,
        channels=(1, codec.CHANNELS),
        channels_required=True,
        note="32-byte frames, 14 channels, 115200 baud 8N1; channels past the list "
        "1000 µs. While a listed channel's node is in failsafe no frame is sent: the "
        'receiver\'s own failsafe takes over (docs/ICD.md, "iBus output").',
        scale=IBUS_SCALE,
        display_name="iBus",
        aliases={"flysky": "FlySky's serial stream is iBus"},
    )
)
