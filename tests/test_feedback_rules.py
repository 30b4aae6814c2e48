"""The config's `feedback:` rules as read (docs/CONFIG.md, "Feedback"): what each key gives,
and every problem with its file, line and key."""

from __future__ import annotations

from typing import Any

import pytest

from usb2rc.config.model import DeviceRef, Rumble, SourceRef, TextPiece
from usb2rc.configfile import ConfigError, Problem, load_config_text
from usb2rc.feedback.rules import SOURCE_NAMES, parse_source

ENTRIES = """devices:
  - name: pad
    match: {vid: 0x054c, pid: 0x09cc}
  - name: throttle
    match: {vid: 0x06a3}
"""


def rules_of(feedback: str) -> Any:
    """The rules read (Any: the tests read optional fields they know are set)."""
    return load_config_text(ENTRIES + "feedback:\n" + feedback, "fb.yaml").feedback


def problems(feedback: str) -> list[Problem]:
    with pytest.raises(ConfigError) as exc:
        load_config_text(ENTRIES + "feedback:\n" + feedback, "fb.yaml")
    return exc.value.problems


def one(feedback: str) -> Problem:
    (problem,) = problems(feedback)
    return problem


FIRST_RULE_LINE = 7  # ENTRIES is 5 lines, then `feedback:`


def test_the_design_example_reads_into_rules() -> None:
    rules = rules_of(
        "  - when: crsf.link_quality < 50\n"
        "    device: pad\n"
        "    rumble: {strong: 1.0, weak: 0.5, ms: 300}\n"
        "  - when: mavlink.armed\n"
        "    device: throttle\n"
        "    led: 0\n"
        "    blink: 2\n"
        '  - device: "06a3:0762"\n'
        '    text: {line: 1, text: "LQ {crsf.link_quality}% {mavlink.mode}"}\n'
    )
    assert rules is not None
    lq, armed, mfd = rules
    assert lq.when is not None and lq.when.source == SourceRef("crsf.link_quality", "number")
    assert (lq.when.op, lq.when.value) == ("<", 50)
    assert lq.device == DeviceRef(entry="pad") and lq.rumble == Rumble(1.0, 0.5, 300)
    assert armed.when is not None and (armed.when.op, armed.when.value) == (None, None)
    assert (armed.leds, armed.blink_hz, armed.device) == ((0,), 2.0, DeviceRef(entry="throttle"))
    assert mfd.when is None and mfd.device == DeviceRef(vid=0x06A3, pid=0x0762)
    assert mfd.text is not None and mfd.text.line == 1
    assert mfd.text.pieces == (
        TextPiece("LQ ", SourceRef("crsf.link_quality", "number")),
        TextPiece("% ", SourceRef("mavlink.mode", "text")),
    )
    assert lq.where is not None and (lq.where.line, lq.where.key) == (7, "feedback[0]")


def test_no_key_is_zero_config_and_an_empty_list_no_rules() -> None:
    assert load_config_text(ENTRIES, "fb.yaml").feedback is None
    assert rules_of("  []\n") == ()


def test_each_action_and_value_kind() -> None:
    (rule,) = rules_of(
        "  - when: mavlink.mode != 'RTL'\n"
        "    led: [1, fire, LED Num Lock]\n"
        "    force: {x: -0.5}\n"
        "    brightness: 0.25\n"
        "    color: [255, 0, 16]\n"
        "    rumble: {weak: 0.3}\n"
        '    text: {line: 2, text: "{crsf.battery_voltage:.1f} V {{ok}}"}\n'
    )
    assert rule.when.value == "RTL" and rule.leds == (1, "fire", "LED Num Lock")
    assert (rule.force, rule.brightness, rule.color) == ((-0.5, 0.0), 0.25, (255, 0, 16))
    assert rule.rumble == Rumble(0.0, 0.3, None)
    assert [(p.literal, p.spec) for p in rule.text.pieces] == [("", ".1f"), (" V {ok}", "")]
    flag, node = rules_of(
        "  - {when: mavlink.failsafe == true, led: 0}\n  - {when: node7.waiting, led: 1}\n"
    )
    assert flag.when.value is True
    assert node.when.source == SourceRef("node7.waiting", "flag", 7)


@pytest.mark.parametrize("name", [n for n in SOURCE_NAMES if "nodeN" not in n])
def test_every_listed_source_parses(name: str) -> None:
    assert isinstance(parse_source(name), SourceRef)


def test_an_unknown_key_names_its_line_and_the_closest_key() -> None:
    p = one("  - when: mavlink.armed\n    leds: 0\n")
    assert (p.source, p.line, p.key) == ("fb.yaml", FIRST_RULE_LINE + 1, "feedback[0].leds")
    assert p.suggestion == "led" and "rumble" in p.allowed


def test_an_unknown_source_names_the_known_ones() -> None:
    p = one("  - when: crsf.lq < 50\n    led: 0\n")
    assert (p.line, p.key, p.message) == (
        FIRST_RULE_LINE,
        "feedback[0].when",
        "unknown source 'crsf.lq'",
    )
    assert p.suggestion == "crsf.link_quality"
    assert "crsf.rssi" in p.allowed and "nodeN.failsafe" in p.allowed
    assert one("  - {when: mavlink.arm, led: 0}\n").suggestion == "mavlink.armed"
    assert one("  - {when: node2.failsafes, led: 0}\n").suggestion == "node2.failsafe"


def test_a_node_out_of_range() -> None:
    p = one("  - {when: node255.failsafe, led: 0}\n")
    assert p.message == "Node-ID 255 is out of range" and "N: 0..254" in p.allowed


def test_an_unknown_device_entry_suggests_the_closest_entry() -> None:
    p = one("  - {device: throtle, led: 0}\n")
    assert (p.line, p.key) == (FIRST_RULE_LINE, "feedback[0].device")
    assert p.message == "no devices: entry is named 'throtle'"
    assert p.suggestion == "throttle" and p.allowed.startswith("pad, throttle, vvvv:pppp")


@pytest.mark.parametrize(
    ("when", "message"),
    [
        ("crsf.link_quality => 50", "not a condition: 'crsf.link_quality => 50'"),
        ("crsf.link_quality = 50", "not a condition: 'crsf.link_quality = 50'"),
        ("crsf.link_quality <", "nothing to compare with after '<'"),
        ("crsf.link_quality < low", "crsf.link_quality compares with a number, not 'low'"),
        ("mavlink.mode < 3", "mavlink.mode is a name: only == and != compare it"),
        ("mavlink.armed >= 1", "mavlink.armed is true or false: only == and != compare it"),
        ("mavlink.armed == yes", "mavlink.armed compares with true or false, not 'yes'"),
    ],
)
def test_bad_conditions(when: str, message: str) -> None:
    p = one(f"  - when: {when}\n    led: 0\n")
    assert (p.line, p.key, p.message) == (FIRST_RULE_LINE, "feedback[0].when", message)


def test_a_rule_needs_an_action() -> None:
    p = one("  - {when: mavlink.armed, device: pad}\n")
    assert (p.key, p.message) == ("feedback[0]", "a rule needs an action")
    assert p.allowed == "led, rumble, force, brightness, color, text"


@pytest.mark.parametrize(
    ("rule", "key", "message"),
    [
        ("{when: downlink, blink: 2, rumble: {strong: 1}}", "blink", "blink needs a led to blink"),
        ("{when: downlink, led: 0, blink: 50}", "blink", "50 is out of range"),
        ("{led: 64}", "led", "64 is out of range"),
        ("{led: []}", "led", "no indicator"),
        ("{rumble: {strong: 1, ms: 300}}", "rumble.ms", "a pulse starts when the rule's"),
        ("{when: downlink, rumble: {ms: 300}}", "rumble", "no motor given"),
        ("{when: downlink, rumble: {strong: 1.5}}", "rumble.strong", "1.5 is out of range"),
        ("{force: {}}", "force", "no force given"),
        ("{force: {x: 2}}", "force.x", "2 is out of range"),
        ("{color: [1, 2]}", "color", "2 values"),
        ("{color: [1, 2, 300]}", "color[2]", "300 is out of range"),
        ("{text: {line: 1}}", "text", "missing text"),
        ("{text: {line: 0, text: a}}", "text.line", "0 is out of range"),
        ("{text: {line: 1, text: '{crsf.lq}'}}", "text.text", "{crsf.lq}: unknown source"),
        (
            "{text: {line: 1, text: '{mavlink.mode:.1f}'}}",
            "text.text",
            "{mavlink.mode}: bad format",
        ),
        ("{text: {line: 1, text: '{'}}", "text.text", "bad text: "),
        ("{text: {line: 1, text: '{downlink!r}'}}", "text.text", "{downlink}: bad format '!r'"),
    ],
)
def test_bad_actions(rule: str, key: str, message: str) -> None:
    p = one(f"  - {rule}\n")
    assert (p.line, p.key) == (FIRST_RULE_LINE, f"feedback[0].{key}")
    assert p.message.startswith(message)


def test_every_problem_of_every_rule_is_reported() -> None:
    found = problems(
        "  - {when: crsf.lq < 50, led: 0}\n  - {device: nobody, led: 0}\n  - {led: 0, colour: 1}\n"
    )
    assert [(p.line, p.key) for p in found] == [
        (FIRST_RULE_LINE, "feedback[0].when"),
        (FIRST_RULE_LINE + 1, "feedback[1].device"),
        (FIRST_RULE_LINE + 2, "feedback[2].colour"),
    ]


def test_feedback_must_be_a_list() -> None:
    p = one("  led: 0\n")
    assert (p.key, p.message) == ("feedback", "expected a list of rules, got a mapping")
    empty = problems("")[0]  # `feedback:` with nothing: not zero config in disguise
    assert (empty.key, empty.allowed) == ("feedback", "[] for none")


def test_a_vid_pid_needs_no_entry() -> None:
    text = 'feedback:\n  - {device: "054C:09CC", rumble: {strong: 1}}\n'
    (rule,) = load_config_text(text, "fb.yaml").feedback or ()
    assert rule.device == DeviceRef(vid=0x054C, pid=0x09CC)
