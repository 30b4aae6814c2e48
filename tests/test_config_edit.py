"""config_edit: calibrations go into the config's text and nothing else in it changes."""

from __future__ import annotations

import difflib

import pytest
from daemon_harness import ROOT
from hypothesis import given, settings
from hypothesis import strategies as st

from usb2rc.commands.config_edit import AxisCalibration, EditError, set_calibrations
from usb2rc.commands.init import read_devices
from usb2rc.commands.starter import starter_config
from usb2rc.configfile import Calibration, load_config_text

HOTAS = (ROOT / "usb2rc" / "data" / "config" / "hotas.yaml").read_text()
CAL = Calibration(10, 500, 1000)


def changed_lines(before: str, after: str) -> list[tuple[str, str]]:
    """(old line, new line) pairs; an inserted line pairs with ""."""
    pairs = []
    matcher = difflib.SequenceMatcher(a=before.splitlines(), b=after.splitlines(), autojunk=False)
    for tag, a0, a1, b0, b1 in matcher.get_opcodes():
        if tag != "equal":
            old, new = before.splitlines()[a0:a1], after.splitlines()[b0:b1]
            pairs += list(zip(old + [""] * (len(new) - len(old)), new, strict=False))
    return pairs


def axis(config_text: str, device: int, slot: str):
    config = load_config_text(config_text, "t.yaml")
    return next(a for a in config.devices[device].axes if a.slot == slot)


def test_hotas_flow_axes_change_on_their_own_line_only():
    updates = [
        AxisCalibration(0, "x", CAL, 0.05),  # has a deadband: replaced
        AxisCalibration(0, "rz", CAL),  # has a calibration: replaced, deadband kept
        AxisCalibration(1, "z", CAL, 0.1),  # has a comment after it
    ]
    edited = set_calibrations(HOTAS, updates, "hotas.yaml")
    assert changed_lines(HOTAS, edited) == [
        (
            "      x:  {usage: X, deadband: 0.02, expo: 0.3}",
            "      x:  {usage: X, deadband: 0.05, expo: 0.3, calibration: "
            "{min: 10, center: 500, max: 1000}}",
        ),
        (
            "      rz: {usage: Rz, calibration: {min: 12, center: 128, max: 250}, deadband: 0.05}",
            "      rz: {usage: Rz, calibration: {min: 10, center: 500, max: 1000}, deadband: 0.05}",
        ),
        (
            "      z:      {usage: Z, failsafe: -32768, arm: low}  # idle when lost; live once "
            "pulled back",
            "      z:      {usage: Z, failsafe: -32768, arm: low, calibration: {min: 10, "
            "center: 500, max: 1000}, deadband: 0.1} # idle when lost; live once pulled back",
        ),
    ]
    assert axis(edited, 0, "x").calibration == CAL and axis(edited, 0, "x").deadband == 0.05
    assert axis(edited, 0, "x").expo == 0.3
    assert axis(edited, 0, "rz").deadband == 0.05
    assert axis(edited, 1, "z").failsafe == -32768


def test_a_comment_keeps_its_column_while_there_is_room():
    text = "devices:\n  - match: {vid: 1}\n    axes:\n      x: {usage: X}" + " " * 60 + "# stick\n"
    edited = set_calibrations(text, [AxisCalibration(0, "x", CAL)], "t.yaml")
    (line,) = [line for line in edited.splitlines() if "# stick" in line]
    assert line.index("# stick") == text.splitlines()[3].index("# stick")


BLOCK = """\
# my joystick
outputs:
- protocol: c2-16b   # the only one
devices:
- match:
    vid: 1      # v
  axes:
    x: X   # shorthand
    y:
      usage: Y
      invert: true   # keep
    rz:
      usage: Rz
      calibration:
        min: 1
        max: 100    # old
      deadband: 0.3
  buttons: {"1-4": "1-4"}
"""


def test_shorthand_block_and_nested_block_mappings():
    updates = [
        AxisCalibration(0, "x", CAL, 0.02),
        AxisCalibration(0, "y", CAL, 0.02),
        AxisCalibration(0, "rz", CAL, 0.01),
    ]
    edited = set_calibrations(BLOCK, updates, "t.yaml")
    assert edited == BLOCK.replace(
        "    x: X   # shorthand",
        "    x: {usage: X, calibration: {min: 10, center: 500, max: 1000}, deadband: 0.02} "
        "# shorthand",
    ).replace(
        "      invert: true   # keep\n",
        "      invert: true   # keep\n"
        "      calibration: {min: 10, center: 500, max: 1000}\n"
        "      deadband: 0.02\n",
    ).replace(
        "        min: 1\n        max: 100    # old\n      deadband: 0.3\n",
        "        min: 10\n        max: 1000    # old\n        center: 500\n      deadband: 0.01\n",
    )
    assert [axis(edited, 0, s).calibration for s in ("x", "y", "rz")] == [CAL] * 3
    assert axis(edited, 0, "y").invert


def test_a_file_without_a_final_newline():
    text = "devices:\n  - match: {vid: 1}\n    axes:\n      x:\n        usage: X"
    edited = set_calibrations(text, [AxisCalibration(0, "x", CAL)], "t.yaml")
    assert edited.endswith("\n        calibration: {min: 10, center: 500, max: 1000}")
    assert axis(edited, 0, "x").calibration == CAL


@pytest.mark.parametrize(
    ("update", "message"),
    [
        (AxisCalibration(3, "x", CAL), "no such device entry"),
        (AxisCalibration(0, "z", CAL), "no `z` mapping"),
        (AxisCalibration(0, "x", CAL, 0.999), "does not pass"),  # deadband past 0.99
    ],
)
def test_an_edit_that_cannot_be_made_raises(update, message):
    with pytest.raises(EditError, match=message):
        set_calibrations(BLOCK, [update], "t.yaml")


def test_a_default_layout_entry_has_no_axes_to_write_into():
    text = "devices:\n  - match: {vid: 1}\n    node_id: 3\n"
    with pytest.raises(EditError, match="no `axes` mapping"):
        set_calibrations(text, [AxisCalibration(0, "x", CAL)], "t.yaml")


STARTER = starter_config(read_devices(str(ROOT / "usb2rc" / "data" / "demo"))[0], "/dev/null")
STARTER_AXES = [
    (i, a.slot, a.where.line)
    for i, d in enumerate(load_config_text(STARTER, "x.yaml").devices)
    for a in d.axes
]


@st.composite
def calibrations(draw: st.DrawFn) -> list[AxisCalibration]:
    chosen = draw(st.lists(st.sampled_from(STARTER_AXES), unique=True, max_size=6))
    out = []
    for device, slot, _line in chosen:
        lo = draw(st.integers(-70000, 70000))
        center = lo + draw(st.integers(1, 5000))
        hi = center + draw(st.integers(1, 5000))
        deadband = draw(st.none() | st.integers(1, 99).map(lambda d: d / 100))
        out.append(AxisCalibration(device, slot, Calibration(lo, center, hi), deadband))
    return out


@settings(max_examples=60, deadline=None)
@given(calibrations())
def test_any_calibrations_read_back_and_only_their_lines_change(updates):
    edited = set_calibrations(STARTER, updates, "x.yaml")
    config = load_config_text(edited, "x.yaml")
    for update in updates:
        got = next(a for a in config.devices[update.device].axes if a.slot == update.slot)
        assert got.calibration == update.calibration
        assert update.deadband is None or got.deadband == update.deadband
    lines = {
        line for d, s, line in STARTER_AXES if any((u.device, u.slot) == (d, s) for u in updates)
    }
    before, after = STARTER.splitlines(), edited.splitlines()
    assert len(before) == len(after)
    for number, (old, new) in enumerate(zip(before, after, strict=True), start=1):
        if number in lines:
            assert new.split("#")[1:] == old.split("#")[1:]  # its comment is still there
        else:
            assert new == old
