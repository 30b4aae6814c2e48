"""The keys only some output protocols take (`line_feed`, `address`, `message`, ...): how to
read each from YAML, its default and its doc line, per protocol name.

Each protocol declares its own in its package (`usb2rc.protocols.<name>`, its registry row's
`options`); registering the row files them here (`add_options`), where the config model finds
their defaults (`OutputConfig.option` falls back to `option_default`) without the registry,
which sits above the codecs and the config.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from yaml.nodes import Node

from usb2rc.config.yamlnodes import NodeReader

OptionReader = Callable[[NodeReader, Node, str], Any]


@dataclass(frozen=True)
class Option:
    """A config key only some protocols take: how to read it, its default, its doc line."""

    read: OptionReader
    default: Any
    doc: str

    @classmethod
    def boolean(cls, default: bool, doc: str) -> Option:
        """A true / false key."""
        return cls(_boolean, default, doc)

    @classmethod
    def choice(cls, choices: tuple[str, ...], default: str, doc: str) -> Option:
        """A key that takes one of `choices`."""

        def read(reader: NodeReader, node: Node, path: str) -> Any:
            return reader.choice(node, path, choices)

        return cls(read, default, doc)


def _boolean(reader: NodeReader, node: Node, path: str) -> Any:
    return reader.boolean(node, path)


_OPTIONS: dict[str, Mapping[str, Option]] = {}  # protocol name -> its own keys, as registered


def add_options(protocol: str, options: Mapping[str, Option]) -> None:
    """A protocol's own keys, as its registry row declares them."""
    _OPTIONS[protocol] = options


def option_default(protocol: str, name: str) -> Any:
    """The default of a protocol's own key (KeyError when the protocol has no such key, or
    its package was not imported: `usb2rc.outputs` imports every protocol's)."""
    return _OPTIONS[protocol][name].default
