"""`scaling.linear_field` (the node step's axis scaling) is docs/ICD.md's "Axis scaling" to
the bit: clamp, `round((v - lo) * 65535 / (hi - lo)) - 32768` with halves to even, worked out
here with exact fractions; `invert` scales lo + hi - v. The compiled steady step works it out
from the function's terms (`scaling.linear_terms`, `_steady.linear_wire`) to the same bit."""

from __future__ import annotations

from fractions import Fraction

from hypothesis import given, settings
from hypothesis import strategies as st

from usb2rc.nodes import steady
from usb2rc.nodes.scaling import linear_field, linear_terms, scale_linear


def compiled_wire(lo: int, hi: int, unsigned: bool, invert: bool, v: int) -> int | None:
    """What the compiled step works out for field 2 = v (None: not built here, or it would
    call the function)."""
    built = steady.compiled()
    if built is None:
        return None
    return built.linear_wire(linear_terms(linear_field(2, lo, hi, unsigned, invert)), (0, 0, v))


def by_the_icd(v: int, lo: int, hi: int, unsigned: bool) -> int:
    if hi <= lo:
        return 32768 if unsigned else 0
    v = min(hi, max(lo, v))
    out = round(Fraction((v - lo) * 65535, hi - lo))  # Fraction rounds halves to even
    return out if unsigned else out - 32768


@settings(max_examples=500, deadline=None)
@given(
    lo=st.integers(-(1 << 31), 1 << 16),
    width=st.integers(-3, 1 << 20),
    v=st.integers(-(1 << 31), 1 << 21),
    unsigned=st.booleans(),
    invert=st.booleans(),
)
def test_the_axis_scaling_of_the_icd(
    lo: int, width: int, v: int, unsigned: bool, invert: bool
) -> None:
    hi = lo + width
    raw = lo + hi - v if invert else v
    assert linear_field(2, lo, hi, unsigned, invert)((0, 0, v), 0) == by_the_icd(
        raw, lo, hi, unsigned
    )
    assert scale_linear(raw, lo, hi, unsigned) == by_the_icd(raw, lo, hi, unsigned)
    in_c = compiled_wire(lo, hi, unsigned, invert, v)
    assert in_c is None or in_c == by_the_icd(raw, lo, hi, unsigned)
    if steady.compiled() is not None and lo < hi and -(1 << 31) <= v < (1 << 31):
        assert in_c is not None  # every 32-bit field of a real range is worked out in C


def test_a_ten_bit_axis_at_its_ends_and_centre() -> None:
    scale = linear_field(0, 0, 1023)
    assert [scale((v,), 0) for v in (0, 511, 512, 1023, -5, 2000)] == [
        -32768,
        -33,
        32,
        32767,
        -32768,
        32767,
    ]


def test_a_half_rounds_to_even() -> None:
    # 1 * 65535 / 6 = 10922.5 and 3 * 65535 / 6 = 32767.5: halves, to the even neighbour
    scale = linear_field(0, 0, 6, unsigned=True)
    assert [scale((1,), 0), scale((3,), 0)] == [10922, 32768]
    if steady.compiled() is not None:
        assert [compiled_wire(0, 6, True, False, v) for v in (1, 3)] == [10922, 32768]
