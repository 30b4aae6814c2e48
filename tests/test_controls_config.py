"""The controls' config errors (usb2rc.config_controls): file:line: key.path, with the
allowed values, and a did-you-mean for a switch name."""

from __future__ import annotations

import pytest

from usb2rc.config import ConfigError, load_config_text

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
