"""Read YAML as a node tree that keeps line numbers; report problems as records.

`compose(text, source)` parses one document into `yaml.nodes` (each node knows its line);
`NodeReader` walks that tree for a schema: it converts scalars (`integer`, `number`,
`boolean`, `string`, `choice`), checks mappings against their allowed keys (unknown keys get
a did-you-mean suggestion) and collects every problem instead of stopping at the first.

A `Problem` is a record: where (file, line, key path), what, and what would be allowed. It is
formatted once, by `Problem.format()`, as `file:line: key.path: message (allowed: ...)`;
`ConfigError` carries the records and, for callers that print, their formatted lines.

This module knows nothing about usb2rc's schema (`usb2rc.configfile` and the config
package's other modules do).
"""

from __future__ import annotations

import dataclasses
import difflib
import re
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any, TypeVar

import yaml
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode

T = TypeVar("T")

_LIST_INDEX = re.compile(r"\[\d+\]")
TOP_LEVEL = "(top level)"  # the key path of the document itself, in messages

# A line of a hid-recorder file's descriptor (`R: <length> <hex bytes>`): such a file given
# as a config is a mix-up worth naming, not 17 "unknown key" errors.
_RECORDING_DESCRIPTOR = re.compile(r"^R: \d+( [0-9a-fA-F]{2})+\s*$", re.MULTILINE)


@dataclass(frozen=True)
class Problem:
    """One problem in a config file: where it is, what is wrong, what would be allowed."""

    source: str  # the file name as given, or e.g. "<config>"
    line: int | None  # 1-based; None: the file as a whole (e.g. it cannot be read)
    key: str | None  # key path such as "devices[0].axes.x"; None: not tied to a key
    message: str
    allowed: str = ""  # what the key accepts, e.g. "0..255" or "true, false"
    suggestion: str | None = None  # the closest valid key or value, for a wrong one

    def format(self) -> str:
        """`file:line: key.path: message; did you mean 'k'? (allowed: ...)`."""
        text = self.source if self.line is None else f"{self.source}:{self.line}"
        if self.key is not None:  # "" is the document itself (a file that is one list)
            text += f": {self.key or TOP_LEVEL}"
        text += f": {self.message}"
        if self.suggestion is not None:
            text += f"; did you mean {self.suggestion!r}?"
        if self.allowed:
            text += f" (allowed: {self.allowed})"
        return text

    def __str__(self) -> str:
        return self.format()


class ConfigError(ValueError):
    """One or more problems in a config; `errors` are their formatted lines, in order.

    `problems` keeps every record; `errors` shows the same problem (same key and message)
    found on many lines once, with its count and lines (`format_grouped`)."""

    def __init__(self, problems: Iterable[Problem]) -> None:
        self.problems: list[Problem] = list(problems)
        self.errors: list[str] = format_grouped(self.problems)
        super().__init__("\n".join(self.errors))


SHOWN_LINES = 5  # of a repeated problem, the first lines named; the rest are counted


def format_grouped(problems: list[Problem]) -> list[str]:
    """One line per distinct problem, in first-seen order. A repeat (same file, message,
    allowed and suggestion, at a key that differs at most in its list indexes) is counted:
    `devices[*].node_id: ... (17 times: lines a, b, ... and M more)`."""
    groups: dict[tuple[object, ...], list[Problem]] = {}
    for problem in problems:
        key = _any_index(problem.key)
        same = (problem.source, key, problem.message, problem.allowed, problem.suggestion)
        groups.setdefault(same, []).append(problem)
    return [_format_group(group) for group in groups.values()]


def _any_index(key: str | None) -> str | None:
    """`devices[3].node_id` -> `devices[*].node_id`: the same key in every list entry."""
    return None if key is None else _LIST_INDEX.sub("[*]", key)


def _format_group(group: list[Problem]) -> str:
    if len(group) == 1:
        return group[0].format()
    first = group[0]
    if any(p.key != first.key for p in group):
        first = dataclasses.replace(first, key=_any_index(first.key))
    text = first.format()
    lines = [str(p.line) for p in group if p.line is not None]
    where = ", ".join(lines[:SHOWN_LINES])
    if len(lines) > SHOWN_LINES:
        where += f" and {len(lines) - SHOWN_LINES} more"
    return f"{text} ({len(group)} times" + (f": lines {where})" if lines else ")")


@dataclass(frozen=True)
class Where:
    """Where a value came from: for problems found after reading (bind, clashes)."""

    source: str
    line: int
    key: str

    def __str__(self) -> str:
        return f"{self.source}:{self.line}: {self.key}"

    def problem(self, message: str, allowed: str = "", *, key_suffix: str = "") -> Problem:
        """A problem at this place; `key_suffix` (".name") names a key below it."""
        return Problem(self.source, self.line, self.key + key_suffix, message, allowed)


# --------------------------------------------------------------------------- text -> nodes


def decode(data: bytes, source: str) -> str:
    """The bytes of a file as text; raises ConfigError naming the line when not UTF-8."""
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        message = f"not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start})"
        raise ConfigError([Problem(source, line, None, message)]) from None


def compose(text: str, source: str) -> Node | None:
    """One YAML document as a node tree (None when empty); raises ConfigError on bad YAML
    and on a hid-recorder file (`reject_recording`)."""
    reject_recording(text, source)
    try:
        node: Node | None = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.MarkedYAMLError as exc:
        raise ConfigError([_yaml_problem(exc, source)]) from None
    except yaml.reader.ReaderError as exc:  # a character YAML does not allow
        line = text[: exc.position].count("\n") + 1
        message = f"not valid YAML: character {exc.character!r} is not allowed"
        raise ConfigError([Problem(source, line, None, message)]) from None
    except RecursionError:
        raise ConfigError([Problem(source, 1, None, "not valid YAML: nested too deeply")]) from None
    return node


def reject_recording(text: str, source: str) -> None:
    """A hid-recorder file is YAML-ish (`R: ...`, `E: ...`): say what it is and what to do."""
    found = _RECORDING_DESCRIPTOR.search(text)
    if found is None:
        return
    line = text[: found.start()].count("\n") + 1
    message = (
        "this is a hid-recorder file (a device's recording), not a config: give its folder "
        "to --replay DIR (`usb2rc run --replay DIR`), or see its layout with "
        f"`usb2rc describe {source}`"
    )
    raise ConfigError([Problem(source, line, None, message)])


def _yaml_problem(exc: yaml.MarkedYAMLError, source: str) -> Problem:
    mark = exc.problem_mark or exc.context_mark
    line = mark.line + 1 if mark else 0
    context = ""
    if exc.context and exc.context_mark:
        context = f" ({exc.context} at line {exc.context_mark.line + 1})"
    return Problem(source, line, None, f"not valid YAML: {exc.problem}{context}")


# --------------------------------------------------------------------------- nodes -> values


def kind(node: Node) -> str:
    """What a node is, for messages: "a mapping", "a list" or the scalar as written."""
    if isinstance(node, MappingNode):
        return "a mapping"
    if isinstance(node, SequenceNode):
        return "a list"
    return show(node)


def show(node: Node) -> str:
    """A node for messages: a scalar as written (repr), "nothing" for an empty one."""
    if isinstance(node, ScalarNode):
        return repr(node.value) if node.value != "" else "nothing"
    return kind(node)


Items = dict[str, tuple[Node, Node]]  # a mapping's items by key: (key node, value node)


class NodeReader:
    """Walks a YAML node tree, converting and checking; collects every problem.

    One per load, with its own constructor: a SafeConstructor remembers every node it has
    built (`constructed_objects`) until a whole document is constructed, which we never do.
    A shared one kept every config ever loaded alive (~100 KB per SIGHUP).
    """

    def __init__(self, source: str) -> None:
        self.source = source
        self.problems: list[Problem] = []
        self._constructor = yaml.constructor.SafeConstructor()

    def where(self, node: Node, path: str) -> Where:
        return Where(self.source, node.start_mark.line + 1, path)

    def error(
        self, node: Node, path: str, message: str, allowed: str = "", suggestion: str | None = None
    ) -> None:
        line = node.start_mark.line + 1
        self.problems.append(Problem(self.source, line, path, message, allowed, suggestion))

    def report(self, problem: Problem) -> None:
        """A problem found without a node at hand (cross-checks over read values)."""
        self.problems.append(problem)

    def mapping(self, node: Node, path: str, allowed_keys: Iterable[str] | None) -> Items | None:
        """A mapping's items by key (key node, value node); unknown / duplicate keys reported."""
        if not isinstance(node, MappingNode):
            self.error(node, path, f"expected a mapping, got {kind(node)}")
            return None
        allowed = list(allowed_keys) if allowed_keys is not None else None
        items: Items = {}
        for key_node, value_node in node.value:
            key = str(self.scalar(key_node)) if isinstance(key_node, ScalarNode) else "?"
            key_path = f"{path}.{key}" if path else key
            if key in items:
                self.error(key_node, key_path, "duplicate key")
            elif allowed is not None and key not in allowed:
                close = difflib.get_close_matches(key, allowed, n=1)
                self.error(
                    key_node,
                    key_path,
                    f"unknown key {key!r}",
                    ", ".join(allowed),
                    close[0] if close else None,
                )
            else:
                items[key] = (key_node, value_node)
        return items

    def scalar(self, node: Node) -> Any:
        if not isinstance(node, ScalarNode):
            return node
        try:
            return self._constructor.construct_object(node, deep=True)
        except (yaml.YAMLError, ValueError, TypeError, OverflowError, AttributeError):
            return node.value  # e.g. `!!int abc`: the type check names the line

    def sequence(self, node: Node, path: str) -> list[Node] | None:
        if not isinstance(node, SequenceNode):
            self.error(node, path, f"expected a list, got {kind(node)}")
            return None
        return list(node.value)

    def list_of(
        self,
        node: Node,
        path: str,
        read_one: Callable[[NodeReader, Node, str], T | None],
        allow_empty: bool = True,
    ) -> tuple[T, ...]:
        """Each entry of a list read by `read_one(reader, entry, "path[i]")`; None dropped."""
        entries = self.sequence(node, path)
        if entries is None:
            return ()
        if not entries and not allow_empty:
            self.error(node, path, "empty list", "at least one entry")
        results = (read_one(self, entry, f"{path}[{i}]") for i, entry in enumerate(entries))
        return tuple(r for r in results if r is not None)

    def integer(self, node: Node, path: str, lo: int, hi: int) -> int | None:
        value = self.scalar(node)
        if not isinstance(value, int) or isinstance(value, bool):
            self.error(node, path, f"expected an integer, got {show(node)}", f"{lo}..{hi}")
            return None
        if not lo <= value <= hi:
            self.error(node, path, f"{value} is out of range", f"{lo}..{hi}")
            return None
        return value

    def number(self, node: Node, path: str, lo: float, hi: float) -> float | None:
        value = self.scalar(node)
        if not isinstance(value, int | float) or isinstance(value, bool):
            self.error(node, path, f"expected a number, got {show(node)}", f"{lo}..{hi}")
            return None
        if not lo <= value <= hi:
            self.error(node, path, f"{value} is out of range", f"{lo}..{hi}")
            return None
        return float(value)

    def boolean(self, node: Node, path: str) -> bool | None:
        value = self.scalar(node)
        if not isinstance(value, bool):
            self.error(node, path, f"expected true or false, got {show(node)}", "true, false")
            return None
        return value

    def string(self, node: Node, path: str) -> str | None:
        value = self.scalar(node)
        if isinstance(value, bool) or not isinstance(value, str | int | float):
            self.error(node, path, f"expected a string, got {show(node)}")
            return None
        return str(value)

    def choice(
        self,
        node: Node,
        path: str,
        choices: Iterable[str],
        aliases: Mapping[str, tuple[str, str]] | None = None,
    ) -> str | None:
        """One of `choices`. A wrong value gets a did-you-mean: from `aliases` (another
        name for a choice, lower case -> (the choice, why)), else the closest choice."""
        options = list(choices)
        value = self.string(node, path)
        if value is None:
            return None
        if value not in options:
            alias = (aliases or {}).get(value.strip().lower())
            message = f"{value!r} is not valid" + (f": {alias[1]}" if alias else "")
            close = difflib.get_close_matches(value, options, n=1)
            suggestion = alias[0] if alias else close[0] if close else None
            self.error(node, path, message, ", ".join(options), suggestion)
            return None
        return value
