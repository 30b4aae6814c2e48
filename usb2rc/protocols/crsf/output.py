"""The CRSF output: its row in the output registry, its own config keys and how it is built
(a `CrsfSession` following its `CrsfModule`, on a serial link); importing this module
registers it."""

from __future__ import annotations

from typing import Any

from yaml.nodes import Node

from usb2rc.config.output_options import Option
from usb2rc.config.yamlnodes import NodeReader
from usb2rc.protocols.channels import OutputChannels
from usb2rc.protocols.crsf import codec
from usb2rc.protocols.crsf.session import CrsfModule, CrsfSession
from usb2rc.protocols.rc11_channels import RC11_SCALE
from usb2rc.protocols.registry import OutputProtocol, fixed_length, register
from usb2rc.wiring import BuiltOutput, OutputContext, on_serial_port

# The RC frames' address byte by the names the config takes: a TX module's, and a flight
# controller's receiver UART.
ADDRESSES = {"module": codec.ADDRESS_MODULE, "flight_controller": codec.ADDRESS_FLIGHT_CONTROLLER}


def _address(reader: NodeReader, node: Node, path: str) -> Any:
    """`module` (0xEE), `flight_controller` (0xC8) or an address byte 0..255, as the byte."""
    if isinstance(reader.scalar(node), int):
        return reader.integer(node, path, 0, 0xFF)
    name = reader.choice(node, path, (*ADDRESSES, "an integer 0..255"))
    return None if name is None else ADDRESSES[name]


OPTIONS = {
    "follow_module": Option.boolean(True, "follow the module's timing-correction frames"),
    "address": Option(
        _address,
        codec.ADDRESS_MODULE,
        "RC frames to `module` (0xEE, a TX module) or `flight_controller` "
        "(0xC8, an FC's receiver UART), or an address byte 0..255",
    ),
}


def build(context: OutputContext) -> BuiltOutput:
    out = context.config
    assert out.port
    sources = context.mapping.sumd_channels(out)
    channels = OutputChannels.scaled(sources, RC11_SCALE, codec.RC_FRAME_LEN)
    module = CrsfModule(
        1.0 / out.rate_hz,
        follow_module=bool(out.option("follow_module")),
        min_interval_s=CRSF.bits_per_second(1.0, len(channels)) / out.baudrate,
    )
    session = CrsfSession(out.port, channels, module, int(out.option("address")))
    return on_serial_port(context, session)


CRSF = register(
    OutputProtocol(
        "crsf",
        "CRSF RC_CHANNELS_PACKED to an ExpressLRS / Crossfire module or a flight controller",
        default_baudrate=400000,
        default_rate_hz=250,
        frame_length=fixed_length(codec.RC_FRAME_LEN),
        decoder=codec.CrsfDecoder,
        build=build,
        channels=(1, 16),
        channels_required=True,
        options=OPTIONS,
        aliases={
            "elrs": "ExpressLRS receivers take CRSF",
            "expresslrs": "ExpressLRS receivers take CRSF",
            "crossfire": "TBS Crossfire receivers take CRSF",
            "tbs": "TBS Crossfire receivers take CRSF",
        },
    )
)
