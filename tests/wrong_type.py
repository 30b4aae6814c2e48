"""An encoder's argument of the wrong type: where the hot path is compiled (mypyc), the call
refuses it before the encoder runs (TypeError: "int object expected; got float"); where it is
interpreted, the encoder's own check does (ValueError, with its message). A bad VALUE of the
right type is the encoder's ValueError on either path: the tests keep those strict.

A bool is an int to the type system: not a wrong type here. In a sequence of ints the
encoders refuse it on either path (their checks see each item as an object); as a single
`int` argument a compiled function takes it as 0 or 1 before the encoder's check runs.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from contextlib import AbstractContextManager, contextmanager

import pytest

from usb2rc import compiled_path


@contextmanager
def refused(match: str) -> Iterator[None]:
    """Like `pytest.raises(ValueError, match=match)` for a wrong-typed argument: a TypeError
    where the hot path is compiled, the ValueError (matching `match`) where it is not."""
    expected = (TypeError, ValueError) if compiled_path.compiled_active() else ValueError
    with pytest.raises(expected) as raised:
        yield
    if raised.type is ValueError:
        assert re.search(match, str(raised.value)), (match, str(raised.value))


def rejected(match: str, *args: object) -> AbstractContextManager[object]:
    """`refused(match)` where one of `args` (the arguments the case changed) is wrongly typed,
    else `pytest.raises(ValueError, match=match)`: a bad value of the right type is the
    encoder's ValueError on either path."""
    if wrongly_typed(*args):
        return refused(match)
    return pytest.raises(ValueError, match=match)


def wrongly_typed(*args: object) -> bool:
    """Whether any of `args` (or an item of a list or tuple among them) is not an int."""
    return any(
        wrongly_typed(*arg) if isinstance(arg, list | tuple) else not isinstance(arg, int)
        for arg in args
    )


def fail_alike(new: tuple[str, object], old: tuple[str, object], *args: object) -> bool:
    """Whether the outcomes (tests/test_codec_packing.py's `outcome`) of a new encoder and the
    old one for `args` agree: the same bytes or the same error where the arguments are
    ints, or where the hot path is interpreted; both an error where one is wrongly typed and
    the new encoder is compiled (its call may refuse that argument before any check whose
    ValueError the old one raised)."""
    if compiled_path.compiled_active() and wrongly_typed(*args):
        return new[0] != "bytes" and old[0] != "bytes"
    return new == old
