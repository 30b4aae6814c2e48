"""Control characters in log lines, escaped in one place.

Log lines carry strings that devices and files choose: a HID product, manufacturer or
serial string, a recording's `N:` name, a file name. Written raw, an ESC or BEL in them
reaches the terminal or the journal viewer that shows the log (recolouring it, ringing,
retitling the window), and a newline fakes a log line of its own. `EscapeFilter`, on the
daemon's log handlers (`install`), writes each such character as a Python escape (`\\x1b`,
`\\x07`, `\\n`): in the values a message is formatted with, every control character;
in the message itself (a format string, or text already formatted with an f-string) every
one but newline and tab, which messages of usb2rc's own use.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Mapping
from typing import Any

# C0 controls, DEL and C1 controls (0x80-0x9f: CSI and OSC on some terminals)
_CONTROLS = re.compile(r"[\x00-\x1f\x7f-\x9f]")
_CONTROLS_BUT_LAYOUT = re.compile(r"[\x00-\x08\x0b-\x1f\x7f-\x9f]")  # keeps \t and \n


def _escaped(match: re.Match[str]) -> str:
    return f"\\x{ord(match.group()):02x}"


def escape(text: str) -> str:
    """`text` with every control character written as `\\xNN` (a device's name, say)."""
    return _CONTROLS.sub(_escaped, text)


def escape_message(text: str) -> str:
    """A whole message: every control character escaped but newline and tab."""
    return _CONTROLS_BUT_LAYOUT.sub(_escaped, text)


def _escape_value(value: Any) -> Any:
    """A message's value: a string escaped; an object whose text has a control character
    (an exception quoting a name) as its escaped text; numbers and the rest as they are."""
    if isinstance(value, str):
        return escape(value)
    if isinstance(value, int | float | bool) or value is None:
        return value
    text = str(value)
    return escape(text) if _CONTROLS.search(text) else value


class EscapeFilter(logging.Filter):
    """Escapes a record's values and message (module docstring); never drops a record."""

    def filter(self, record: logging.LogRecord) -> bool:
        args = record.args
        if isinstance(args, Mapping):
            record.args = {key: _escape_value(value) for key, value in args.items()}
        elif args:
            record.args = tuple(_escape_value(value) for value in args)
        message = record.getMessage()
        record.msg, record.args = escape_message(message), None
        return True


def install(logger: logging.Logger | None = None) -> None:
    """Put an `EscapeFilter` on each handler of `logger` (the root logger by default)."""
    for handler in (logger or logging.getLogger()).handlers:
        if not any(isinstance(f, EscapeFilter) for f in handler.filters):
            handler.addFilter(EscapeFilter())
