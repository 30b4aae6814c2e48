"""SampleRing (usb2rc.runtime.samples) against the deque it replaces: the same samples kept,
in the same order, and `take_new` gives each sample once while it is kept."""

from __future__ import annotations

from collections import deque

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from usb2rc.runtime.samples import SampleRing

OPS = st.lists(
    st.one_of(
        st.tuples(st.just("append"), st.floats(allow_nan=False, width=64)),
        st.tuples(st.just("read"), st.none()),
        st.tuples(st.just("take"), st.none()),
    ),
    max_size=200,
)


@settings(max_examples=300, deadline=None)
@given(st.integers(1, 12), OPS)
def test_a_ring_keeps_what_a_deque_with_maxlen_keeps(size: int, ops: list) -> None:
    ring, model = SampleRing(size), deque(maxlen=size)
    new: list[float] = []  # appended since the last take (the model's: unbounded)
    for op, value in ops:
        if op == "append":
            ring.append(value)
            model.append(value)
            new.append(value)
        elif op == "read":
            assert ring.values() == list(model)
        else:
            assert ring.take_new() == new[-size:]  # the oldest are gone once overwritten
            new = []
        assert len(ring) == len(model)


def test_a_ring_holds_doubles_bit_for_bit() -> None:
    ring = SampleRing(3)
    for value in (0.1, 1e-300, -2.5, 0.020000000000000004):
        ring.append(value)
    assert ring.values() == [1e-300, -2.5, 0.020000000000000004]


def test_an_empty_ring_is_refused() -> None:
    with pytest.raises(ValueError, match="at least one"):
        SampleRing(0)
