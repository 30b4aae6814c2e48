"""The controls' config errors (usb2rc.config.controls): file:line: key.path, with the
allowed values, and a did-you-mean for a switch name."""

from __future__ import annotations

import pytest

from usb2rc.configfile import ConfigError, load_config_text

HEAD = """switches:
  gear: {toggle: node0.button3}
  mode: {steps: [node0.button4, node0.button5], positions: 3}
"""


def problems(text: str) -> list[str]:
    with pytest.raises(ConfigError) as refused:
        load_config_text(HEAD + text, "c.yaml")
    return [str(p) for p in refused.value.problems]


def sumd(channels: str) -> str:
    return f"outputs:\n  - protocol: sumd\n    port: /dev/null\n    channels: {channels}\n"


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (
            "  bad: {toggle: node0.button3, latch: node0.button4}\n",
            "c.yaml:4: switches.bad: give exactly one switch kind (allowed: toggle, latch, "
            "steps, hat_switch)",
        ),
        (
            "  bad: {toggle: node0.x}\n",
            "c.yaml:4: switches.bad.toggle: 'node0.x' is not a node button (allowed: "
            "nodeN.buttonK (K 1..56))",
        ),
        (
            "  bad: {steps: [node0.button1, node1.button2]}\n",
            "c.yaml:4: switches.bad.steps: buttons of one node only",
        ),
        (
            "  bad: {steps: node0.button1, positions: 3, initial: 3}\n",
            "c.yaml:4: switches.bad.initial: 3 is out of range (allowed: 0..2)",
        ),
        (
            sumd("[node0.x, switch.gaer]"),
            "c.yaml:7: outputs[0].channels[1]: no switch 'gaer' (did you mean 'gear'?) "
            "(allowed: gear, mode)",
        ),
        (
            sumd("[node0.x, {mix: [{source: node0.y, curve: [0, 1]}]}]"),
            "c.yaml:7: outputs[0].channels[1].mix[0].curve: 2 points (allowed: 3..17 points)",
        ),
        (
            sumd("[node0.y, {mix: [{source: node0.x, rates: {switch: mode, weights: [1, 0.5]}}]}]"),
            "c.yaml:7: outputs[0].channels[1]: 2 rates for switch 'mode' of 3 positions "
            "(allowed: 3 weights)",
        ),
        (
            "throttle_cut: {switch: cutt, channel: node0.z}\n",
            "c.yaml:4: throttle_cut: no switch 'cutt' (allowed: gear, mode)",
        ),
        (
            "outputs:\n  - protocol: mavlink\n    port: udpout:127.0.0.1:14550\n"
            "    actions:\n      - {switch: mode, position: 3, do: rtl}\n",
            "c.yaml:8: outputs[0].actions[0]: switch 'mode' has no position 3 (allowed: 0..2)",
        ),
        (
            "outputs:\n  - protocol: mavlink\n    port: udpout:127.0.0.1:14550\n"
            "    actions:\n      - {button: node0.button1, do: arm, hold: 0}\n",
            "c.yaml:8: outputs[0].actions[0].hold: arm and disarm need a hold (allowed: 0 < "
            "hold <= 10 (seconds))",
        ),
        (
            "outputs:\n  - protocol: mavlink\n    port: udpout:127.0.0.1:14550\n"
            "    actions:\n      - {button: node0.button1, do: takeoff}\n",
            "c.yaml:8: outputs[0].actions[0].do: 'takeoff' is not valid (allowed: arm, "
            "disarm, rtl, land)",
        ),
    ],
)
def test_a_problem_names_its_line_and_key(text: str, expected: str) -> None:
    assert problems(text) == [expected]


def test_icd_lists_switches_mixes_and_actions() -> None:
    from usb2rc.commands.icd import document, json_document

    config = load_config_text(
        HEAD
        + "throttle_cut: {switch: gear, channel: node0.z}\n"
        + "outputs:\n  - protocol: sumd\n    port: /dev/null\n"
        + "    channels: [switch.mode, {mix: [{source: node0.x, curve: {expo: 0.3}}]}]\n"
        + "  - protocol: mavlink\n    port: udpout:127.0.0.1:14550\n"
        + "    actions:\n      - {switch: mode, position: 2, do: {mode: RTL}}\n",
        "c.yaml",
    )
    doc = json_document(config)
    assert doc["switches"][1]["int16"] == "-32768 / 0 / 32767"
    assert doc["mixes"] == [{"output": 1, "channel": 2, "lines": "clamp(1 × expo 0.3(node0.x))"}]
    assert doc["actions"] == [
        {"output": 2, "trigger": "switch.mode at 2", "do": "mode RTL (DO_SET_MODE)", "hold_s": "0"}
    ]
    assert doc["throttle_cuts"] == [{"switch": "gear", "channel": "node0.z"}]
    text = "\n".join(document(config, "text"))
    assert "switch.mode  steps" in text and "Throttle cut: node0.z" in text
    assert "| 1 | switch.mode | switch | 1100..1900 |" in "\n".join(document(config, "markdown"))


def test_init_writes_a_commented_switch_and_action_that_check_takes() -> None:
    from usb2rc.commands.starter import ACTIONS_EXAMPLE, SWITCHES_EXAMPLE, starter_config

    text = starter_config([], "/dev/serial0")
    example_lines = {*ACTIONS_EXAMPLE, *SWITCHES_EXAMPLE}
    uncommented = [
        line.replace("# ", "", 1) if line.strip().removeprefix("# ") in example_lines else line
        for line in text.splitlines()
    ]
    assert uncommented != text.splitlines()
    load_config_text(text, "init.yaml")  # as written: the examples are comments
    config = load_config_text("\n".join(uncommented), "init.yaml")
    assert [s.name for s in config.switches] == ["gear", "mode"]
    assert [a.kind for a in config.outputs[1].option("actions")] == ["arm", "mode"]


def test_a_switch_button_or_slot_the_pinned_entry_does_not_allow() -> None:
    text = (
        "switches:\n  lights: {toggle: node0.button9, slot: x}\n"
        "devices:\n  - name: box\n    match: {vid: 0x1234}\n    node_id: 0\n"
        "    axes: {x: {usage: X}}\n    buttons: {1: 1, 2: 2}\n"
    )
    with pytest.raises(ConfigError) as refused:
        load_config_text(text, "c.yaml")
    assert [str(p) for p in refused.value.problems] == [
        "c.yaml:2: switches.lights: node0.button9: no device feeds button 9 of node 0",
        "c.yaml:2: switches.lights.slot: slot x of node 0 is fed by 'box' too",
    ]
