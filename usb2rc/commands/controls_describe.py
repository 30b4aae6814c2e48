"""The controls as `icd` (text and `--json`) describes them: switches (their
values on the wire), throttle cuts, mixes (their lines) and MAVLink actions."""

from __future__ import annotations

from typing import Any

from usb2rc.config.controls_model import ActionConfig, MixInput, MixRef, SwitchConfig
from usb2rc.configfile import Config
from usb2rc.nodes.curves import position_value

SWITCH_KEYS = ("switch", "kind", "buttons", "positions", "int16", "initial", "failsafe", "slot")
MIX_KEYS = ("output", "channel", "lines")
ACTION_KEYS = ("output", "trigger", "do", "hold_s")


def switch_row(switch: SwitchConfig) -> list[object]:
    values = " / ".join(str(position_value(p, switch.positions)) for p in range(switch.positions))
    failsafe = "hold" if switch.failsafe is None else switch.failsafe
    buttons = ", ".join(b.name for b in switch.buttons)
    if switch.reset is not None:
        buttons += f" (reset {switch.reset.name})"
    return [
        f"switch.{switch.name}", switch.kind, buttons, switch.positions, values,
        switch.initial, failsafe, switch.slot or "",
    ]  # fmt: skip


def mix_line_text(line: MixInput) -> str:
    text = f"{line.weight:g} × "
    if line.curve is not None and line.curve.expo is not None:
        text += f"expo {line.curve.expo:g}({line.source.name})"
    elif line.curve is not None:
        points = ", ".join(f"{p:g}" for p in line.curve.points)
        text += f"curve [{points}]({line.source.name})"
    else:
        text += line.source.name
    if line.rates is not None:
        weights = " / ".join(f"{w:g}" for w in line.rates.weights)
        text += f" × rate ({weights} by switch.{line.rates.switch})"
    return text + (f" {line.offset:+g}" if line.offset else "")


def mix_rows(config: Config) -> list[list[object]]:
    rows: list[list[object]] = []
    for i, output in enumerate(config.outputs, start=1):
        for k, channel in enumerate(output.channels or (), start=1):
            if isinstance(channel, MixRef):
                text = " + ".join(mix_line_text(line) for line in channel.inputs)
                rows.append([i, k, f"clamp({text})"])
    return rows


def action_text(action: ActionConfig) -> str:
    if action.kind == "mode":
        return f"mode {action.mode} (DO_SET_MODE)"
    if action.kind == "command_long":
        params = ", ".join(f"{p:g}" for p in action.params)
        return f"COMMAND_LONG {action.command} [{params}]"
    return action.kind


def action_rows(config: Config) -> list[list[object]]:
    rows: list[list[object]] = []
    for i, output in enumerate(config.outputs, start=1):
        if output.protocol != "mavlink":
            continue
        for action in output.option("actions"):
            trigger = (
                action.button.name
                if action.button
                else (f"switch.{action.switch} at {action.position}")
            )
            rows.append([i, trigger, action_text(action), f"{action.hold:g}"])
    return rows


def cut_lines(config: Config) -> list[str]:
    return [
        f"Throttle cut: {cut.channel.name} held at its low end while switch.{cut.switch} is "
        "off position 0; released when the throttle is low again."
        for cut in config.throttle_cuts
    ]


def controls_record(config: Config) -> dict[str, Any]:
    """The `--json` fields (empty lists without controls)."""

    def records(keys: tuple[str, ...], rows: list[list[object]]) -> list[dict[str, object]]:
        return [dict(zip(keys, row, strict=True)) for row in rows]

    return {
        "switches": records(SWITCH_KEYS, [switch_row(s) for s in config.switches]),
        "throttle_cuts": [
            {"switch": c.switch, "channel": c.channel.name} for c in config.throttle_cuts
        ],
        "mixes": records(MIX_KEYS, mix_rows(config)),
        "actions": records(ACTION_KEYS, action_rows(config)),
    }
