"""`usb2rc icd --json`: the application ICD's tables as one JSON document, for scripts.

The rows are the ones the markdown / text document prints (usb2rc.commands.icd), each a
record; values are the same (an axis range "-32768..32767", a failsafe "hold last" or a
number):

    {"config": FILE | null,
     "outputs": [{"protocol", "port", "baudrate", "rate_hz"}],
     "nodes": [{"node_id", "devices": [{"name", "match", "default_layout"}],
                "axes": [{"slot", "device", "source", "kind", "range", "failsafe", "shaping"}],
                "buttons": [{"button", "group", "bit", "device", "source"}],
                "hats": [{"switch", "bit", "direction", "device", "hat"}]}],
     "devices_without_entry": "default layout, automatic node" | "ignored",
     "sumd": [{"output", "port", "channels": [{"channel", "source", "kind", "us"}]}],
     "replay": [...]}                                   # with --replay DIR only
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from collections.abc import Sequence
from typing import Any

from usb2rc.commands.check import bind_replay, load_or_default
from usb2rc.commands.check_json import device_record, output_records
from usb2rc.commands.icd import axis_rows, button_rows, hat_rows, sumd_rows
from usb2rc.config import Config, ConfigError, DeviceConfig
from usb2rc.mapping import compile_mapping

AXIS_KEYS = ("slot", "device", "source", "kind", "range", "failsafe", "shaping")
BUTTON_KEYS = ("button", "group", "bit", "device", "source")
HAT_KEYS = ("switch", "bit", "direction", "device", "hat")
SUMD_KEYS = ("channel", "source", "kind", "us")


def records(keys: Sequence[str], rows: Sequence[Sequence[object]]) -> list[dict[str, object]]:
    return [dict(zip(keys, row, strict=True)) for row in rows]


def device_entry(device: DeviceConfig) -> dict[str, Any]:
    match = {k: v for k, v in dataclasses.asdict(device.match).items() if v is not None}
    return {"name": device.name, "match": match, "default_layout": device.default_layout}


def node_record(config: Config, node_id: int) -> dict[str, Any]:
    devices = [d for d in config.devices if d.node_id == node_id]
    configured = [d for d in devices if not d.default_layout]
    return {
        "node_id": node_id,
        "devices": [device_entry(d) for d in devices],
        "axes": records(AXIS_KEYS, axis_rows(configured)),
        "buttons": records(BUTTON_KEYS, button_rows(configured)),
        "hats": records(HAT_KEYS, hat_rows(configured)),
    }


def document(config: Config) -> dict[str, Any]:
    mapping = compile_mapping(config)
    return {
        "config": config.source,
        "outputs": output_records(config),
        "nodes": [node_record(config, n) for n in sorted(mapping.pinned_node_ids())],
        "devices_without_entry": (
            "default layout, automatic node" if config.defaults else "ignored"
        ),
        "sumd": [
            {
                "output": i + 1,
                "port": out.port,
                "channels": records(SUMD_KEYS, sumd_rows(mapping, out)),
            }
            for i, out in enumerate(config.outputs)
            if out.protocol == "sumd"
        ],
    }


def run(args: argparse.Namespace) -> int:
    try:
        config = load_or_default(args.config)
    except ConfigError as exc:
        print("\n".join(exc.errors), file=sys.stderr)
        return 2
    doc = document(config)
    if args.replay:
        devices, problems = bind_replay(compile_mapping(config), args.replay)
        doc["replay"] = [device_record(d) for d in devices]
        doc["replay_problems"] = problems
    print(json.dumps(doc, indent=2, ensure_ascii=False))
    return 0
