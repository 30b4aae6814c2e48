"""The keys only some output protocols take (`line_feed`, `address`, `message`, ...): per
protocol name, how to read each from YAML, its default and its doc line.

The config side of the output registry (`usb2rc.outputs`): the registry points each
protocol's entry at its options here, and `OutputConfig.option` falls back to the defaults
here, so the config model needs no registry (which sits above the codecs and the config).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from yaml.nodes import Node

from usb2rc.config import mavlink as config_mavlink
from usb2rc.config.yamlnodes import NodeReader

OptionReader = Callable[[NodeReader, Node, str], Any]


@dataclass(frozen=True)
class Option:
    """A config key only some protocols take: how to read it, its default, its doc line."""

    read: OptionReader
    default: Any
    doc: str


def _boolean(reader: NodeReader, node: Node, path: str) -> Any:
    return reader.boolean(node, path)


def _service_status(reader: NodeReader, node: Node, path: str) -> Any:
    return reader.choice(node, path, ("ascii", "binary"))


# The CRSF address bytes by the names the config takes: a TX module's and a flight
# controller's receiver UART (`crsf.codec.ADDRESS_MODULE` / `ADDRESS_FLIGHT_CONTROLLER`,
# held equal by tests/test_structure.py: the config sits below the codecs).
CRSF_ADDRESSES = {"module": 0xEE, "flight_controller": 0xC8}


def _crsf_address(reader: NodeReader, node: Node, path: str) -> Any:
    """`module` (0xEE), `flight_controller` (0xC8) or an address byte 0..255, as the byte."""
    if isinstance(reader.scalar(node), int):
        return reader.integer(node, path, 0, 0xFF)
    name = reader.choice(node, path, (*CRSF_ADDRESSES, "an integer 0..255"))
    return None if name is None else CRSF_ADDRESSES[name]


OPTIONS: dict[str, Mapping[str, Option]] = {
    "c2-16b": {
        "line_feed": Option(_boolean, True, "LF (0x0A) after each 35-byte frame"),
        "service_status": Option(
            _service_status, "ascii", "service frame status `'1'..'8'` or 0x01..0x08"
        ),
    },
    "sumd": {
        "extended": Option(_boolean, False, "axes onto 900-2100 µs, not 1100-1900 µs"),
    },
    "crsf": {
        "follow_module": Option(_boolean, True, "follow the module's timing-correction frames"),
        "address": Option(
            _crsf_address,
            CRSF_ADDRESSES["module"],
            "RC frames to `module` (0xEE, a TX module) or `flight_controller` "
            "(0xC8, an FC's receiver UART), or an address byte 0..255",
        ),
    },
    "mavlink": {k: Option(*spec) for k, spec in config_mavlink.OPTION_SPECS.items()},
}


def option_default(protocol: str, name: str) -> Any:
    """The default of a protocol's own key (KeyError when the protocol has no such key)."""
    return OPTIONS[protocol][name].default
