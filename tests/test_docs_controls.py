"""docs/CONFIG.md's controls examples ("Switches", "Mixes and curves", "Throttle cut",
"MAVLink actions", "Feedback") load as written, and mean what the text says."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import pytest

from usb2rc.config.controls_model import MixRef
from usb2rc.config.layout import AXIS_NAMES
from usb2rc.configfile import Config, load_config_text
from usb2rc.feedback.engine import DEFAULT_RULES, DeviceSlot, FeedbackEngine, Sources
from usb2rc.feedback.model import CrsfTelemetry, MavlinkTelemetry
from usb2rc.hid.outputs import Capabilities
from usb2rc.nodes.curves import position_value, to_int16
from usb2rc.nodes.mapping import compile_mapping
from usb2rc.nodes.table import NodeFrame
from usb2rc.protocols.channels import int16_value

CONFIG_MD = Path(__file__).resolve().parent.parent / "docs" / "CONFIG.md"
SECTIONS = ("Switches", "Mixes and curves", "Throttle cut", "MAVLink actions")


def examples(section: str) -> list[str]:
    text = CONFIG_MD.read_text(encoding="utf-8")
    body = text.split(f"\n## {section}\n", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"```yaml\n(.*?)```", body, re.DOTALL)


def loaded(section: str) -> Config:
    (example,) = examples(section)
    return load_config_text(example, f"CONFIG.md {section}")


@pytest.mark.parametrize("section", SECTIONS)
def test_each_example_loads(section: str) -> None:
    assert loaded(section).outputs


def test_the_switches_example() -> None:
    config = loaded("Switches")
    kinds = {s.name: (s.kind, s.positions) for s in config.switches}
    assert kinds["mode"] == ("steps", 3) and kinds["view"] == ("hat_switch", 4)
    assert kinds["gear"] == ("toggle", 2) and kinds["horn"] == ("latch", 2)
    lights = next(s for s in config.switches if s.name == "lights")
    assert (lights.slot, lights.failsafe) == ("aux1", 0)


def frame(node: int, switches: tuple[tuple[str, int], ...] = (), **axes: int) -> NodeFrame:
    values = [0] * len(AXIS_NAMES)
    for slot, value in axes.items():
        values[AXIS_NAMES.index(slot)] = value
    return NodeFrame(node, False, tuple(values), 0, 0, 0, switches=switches)


def test_the_mixes_example_means_what_the_text_says() -> None:
    config = loaded("Mixes and curves")
    toe, throttle, aileron, _ = compile_mapping(config).sumd_channels(config.outputs[0])
    assert isinstance((config.outputs[0].channels or ())[0], MixRef)
    nodes = {
        0: frame(0, (("rate", position_value(1, 3)),), x=32767, z=-24575),
        1: frame(1, rx=32767, ry=-32768),
    }
    assert int16_value(toe)(nodes)[0] == to_int16(-1.0)  # left brake full, right released
    # z at -0.75: halfway between the points -1 and -0.2
    assert int16_value(throttle)(nodes)[0] == pytest.approx(to_int16(-0.6), abs=2)
    assert int16_value(aileron)(nodes)[0] == to_int16(0.7)  # full stick at the 70 % rate


def test_the_throttle_cut_and_actions_examples() -> None:
    (cut,) = loaded("Throttle cut").throttle_cuts
    assert (cut.switch, cut.channel.name) == ("cut", "node0.z")
    actions = loaded("MAVLink actions").outputs[0].option("actions")
    assert [a.kind for a in actions] == ["arm", "disarm", "mode", "rtl", "land", "command_long"]
    assert [a.hold for a in actions] == [1.0, 1.0, 0.0, 0.0, 0.0, 0.0]


def test_every_feedback_example_loads() -> None:
    found = examples("Feedback")
    assert len(found) == 2
    for example in found:
        assert load_config_text(example, "CONFIG.md Feedback").feedback


def test_the_feedback_example_means_what_the_text_says() -> None:
    rules = load_config_text(examples("Feedback")[0], "CONFIG.md Feedback").feedback
    lightbar = Capabilities(analog=("rumble_strong", "rumble_weak", "red", "green", "blue"))
    mfd = Capabilities(indicators=1, text_lines=3, text_width=16)
    slots = (
        DeviceSlot("pad", 0, "pad", 0x054C, 0x09CC, True, lightbar),
        DeviceSlot("throttle", 1, "throttle", 0x044F, 0x0404, False, Capabilities(indicators=2)),
        DeviceSlot("mfd", 1, None, 0x06A3, 0x0762, False, mfd),
    )
    engine = FeedbackEngine(rules)
    vehicle = MavlinkTelemetry(armed=True, mode="LOITER", battery_remaining=15, at=0.0)
    engine.step(0.0, Sources(crsf=CrsfTelemetry(link_quality=90, at=0.0)), slots)
    link = CrsfTelemetry(link_quality=40, battery_v=11.06, at=0.1)
    states = dict(engine.step(0.1, Sources(crsf=link, mavlink=vehicle), slots).states)
    assert states["pad"].analog == (  # the pulse, and the low battery's red
        ("rumble_strong", 1.0),
        ("rumble_weak", 0.5),
        ("red", 1.0),
    )
    assert states["throttle"].indicators == 0b1  # armed: led 0 blinks at 2 Hz, lit now
    assert states["mfd"].texts == ("LQ 40% LOITER", "11.1 V 15%")
    later = dict(engine.step(0.45, Sources(crsf=link, mavlink=vehicle), slots).states)
    assert later["throttle"].indicators == 0  # the blink's dark half
    assert later["pad"].analog == (("red", 1.0),)  # the pulse is over


def test_the_zero_config_example_is_the_default_rule_for_one_pad() -> None:
    (rule,) = load_config_text(examples("Feedback")[1], "CONFIG.md Feedback").feedback or ()
    (default,) = DEFAULT_RULES
    assert rule.device is not None and rule.device.entry == "pad"
    assert rule == dataclasses.replace(default, device=rule.device)
