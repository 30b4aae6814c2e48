"""The calibration wizard's decisions, without a terminal: samples and keys in, results out."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from usb2rc.config.calibration import (
    DEADBAND_MARGIN,
    MAX_SUGGESTED_DEADBAND,
    REST_SAMPLES,
    AxisTarget,
    Step,
    Wizard,
    rest_noise,
    suggest_deadband,
)
from usb2rc.configfile import Calibration

X = AxisTarget(0, "stick", "x", "X", 1, 0, 1023)
THROTTLE = AxisTarget(0, "stick", "slider", "Slider", 2, 0, 255, deadband=0.1)


def sweep(wizard: Wizard, lo: int, hi: int) -> None:
    for value in range(lo, hi + 1, 7):
        wizard.observe(value)
    wizard.observe(hi)


def rest(wizard: Wizard, values: list[int]) -> None:
    for i in range(REST_SAMPLES):
        wizard.observe(values[i % len(values)])


def test_range_then_rest_gives_min_median_centre_max_and_a_deadband():
    wizard = Wizard([X])
    sweep(wizard, 3, 1020)
    wizard.key("enter")
    assert wizard.step is Step.REST
    rest(wizard, [510, 512, 514, 512])
    wizard.key("enter")
    assert wizard.step is Step.SUMMARY
    (result,) = wizard.results
    assert result.calibration == Calibration(3, 512, 1020)
    assert result.noise == pytest.approx(2 / 508)
    assert result.suggested_deadband == 0.01 == result.deadband
    wizard.key("enter")
    assert wizard.step is Step.WRITE


def test_extremes_between_two_looks_count():
    wizard = Wizard([X])
    wizard.observe(500, low=0, high=1023)  # a flick to both ends between two refreshes
    wizard.key("enter")
    rest(wizard, [511])
    wizard.key("enter")
    assert wizard.results[0].calibration == Calibration(0, 511, 1023)
    assert wizard.results[0].suggested_deadband == 0.0


def test_enter_waits_for_travel_and_for_rest():
    wizard = Wizard([X])
    wizard.observe(500)
    wizard.observe(520)  # 2 % of the range
    wizard.key("enter")
    assert wizard.step is Step.RANGE and "whole range" in wizard.message
    sweep(wizard, 0, 1023)
    wizard.key("enter")
    wizard.observe(512)
    wizard.key("enter")
    assert wizard.step is Step.REST and "rest a moment longer" in wizard.message


def test_a_throttle_resting_at_an_end_takes_the_midpoint_with_m():
    wizard = Wizard([THROTTLE])
    sweep(wizard, 0, 255)
    wizard.key("enter")
    rest(wizard, [0])
    wizard.key("enter")
    assert wizard.step is Step.REST and "press m" in wizard.message
    wizard.key("m")
    (result,) = wizard.results
    assert result.calibration == Calibration(0, 127, 255)
    assert result.deadband is None  # no centre, no deadband suggestion


def test_an_axis_that_moves_while_resting_is_refused():
    wizard = Wizard([X])
    sweep(wizard, 0, 1023)
    wizard.key("enter")
    rest(wizard, [400, 600])
    wizard.key("enter")
    assert wizard.step is Step.REST and "moved while resting" in wizard.message
    wizard.key("r")  # start this axis again
    assert wizard.step is Step.RANGE and wizard.range.low is None


def test_skip_and_quit():
    wizard = Wizard([X, THROTTLE])
    wizard.key("s")
    assert wizard.target == THROTTLE and wizard.skipped == [X]
    wizard.key("q")
    assert wizard.step is Step.QUIT and wizard.finished and wizard.results == []


def test_a_deadband_the_user_chose_is_never_lowered():
    wizard = Wizard([THROTTLE])  # deadband 0.1 in the config
    sweep(wizard, 0, 255)
    wizard.key("enter")
    rest(wizard, [127, 129])
    wizard.key("enter")
    (result,) = wizard.results
    assert 0 < result.suggested_deadband < 0.1 and result.deadband is None


def test_keys_from_the_summary():
    wizard = Wizard([])
    assert wizard.step is Step.SUMMARY
    wizard.key("s")
    wizard.key("m")
    assert wizard.step is Step.SUMMARY
    wizard.key("w")
    assert wizard.step is Step.WRITE


@given(
    st.integers(-40000, 40000),
    st.integers(2, 40000),
    st.integers(2, 40000),
    st.integers(0, 100),
    st.integers(0, 100),
)
def test_the_suggested_deadband_covers_the_spread_at_rest(lo, below, above, down, up):
    cal = Calibration(lo, lo + below, lo + below + above)
    low, high = cal.center - min(down, below), cal.center + min(up, above)
    noise = rest_noise(low, high, cal)
    suggested = suggest_deadband(noise)
    assert suggested >= noise * DEADBAND_MARGIN - 1e-9
    assert suggested == 0 or suggested < noise * DEADBAND_MARGIN + 0.01
    assert round(suggested, 2) == suggested
    if noise * DEADBAND_MARGIN <= MAX_SUGGESTED_DEADBAND:
        # the rest values read as 0 through the deadband (docs/CONFIG.md, "Axes": shaped axes)
        for v in (low, high):
            x = (v - cal.center) / ((cal.center - cal.min) if v < cal.center else above)
            assert abs(x) <= suggested
