"""The C2-16B output: its row in the output registry, its own config keys and how it is
built (a `C2Session` on a serial link); importing this module registers it."""

from __future__ import annotations

from usb2rc.config.output_options import Option
from usb2rc.protocols.c2_16b import codec
from usb2rc.protocols.c2_16b.engine import C2Settings
from usb2rc.protocols.c2_16b.session import C2Session
from usb2rc.protocols.registry import OutputProtocol, fixed_length, register
from usb2rc.wiring import BuiltOutput, OutputContext, on_serial_port

OPTIONS = {
    "line_feed": Option.boolean(True, "LF (0x0A) after each 35-byte frame"),
    "service_status": Option.choice(
        ("ascii", "binary"), "ascii", "service frame status `'1'..'8'` or 0x01..0x08"
    ),
}


def build(context: OutputContext) -> BuiltOutput:
    out = context.config
    assert out.port
    settings = C2Settings(
        rate_hz=out.rate_hz,
        baudrate=out.baudrate,
        line_feed=out.line_feed,
        binary_status=out.service_status == "binary",
        version=context.version,
    )
    return on_serial_port(context, C2Session(out.port, settings))


C2_16B = register(
    OutputProtocol(
        "c2-16b",
        "SERaero C2-16B: a data frame per node, service frames",
        default_baudrate=115200,
        default_rate_hz=50,
        frame_length=fixed_length(codec.FRAME_LEN + 1),
        decoder=codec.Decoder,
        build=build,
        options=OPTIONS,
    )
)
