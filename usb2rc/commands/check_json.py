"""`usb2rc check --json`: the same verdict as `check`, as one JSON document on stdout.

    {"config": FILE | null, "ok": bool,
     "problems": [{"file", "line", "key", "message", "severity", "allowed", "suggestion"}],
     "outputs": [...], "replay": [...]}   # replay: with --replay DIR only

Every config problem is an `error` (exit 2, as without --json); with `--replay DIR`, a device
that cannot be bound is an `error` too (at the config line it names, `recording`: which
device) and a file in DIR that is no
usable recording a `warning` (the exit stays 0, as the text summary only lists it).
"""

from __future__ import annotations

import argparse
import json
import re
from typing import Any

from usb2rc.commands.check import BoundDevice, bind_replay, load_or_default
from usb2rc.config import Config, ConfigError, Problem
from usb2rc.mapping import compile_mapping


def problem_record(problem: Problem, severity: str = "error") -> dict[str, Any]:
    return {
        "file": problem.source,
        "line": problem.line,
        "key": problem.key,
        "message": problem.message,
        "severity": severity,
        "allowed": problem.allowed or None,
        "suggestion": problem.suggestion,
    }


def output_records(config: Config) -> list[dict[str, Any]]:
    return [
        {
            "protocol": out.protocol,
            "port": out.port,
            "baudrate": out.baudrate,
            "rate_hz": out.rate_hz,
        }
        for out in config.outputs
    ]


def device_record(device: BoundDevice) -> dict[str, Any]:
    info = device.info
    return {
        "file": info.path,
        "vid": info.vid,
        "pid": info.pid,
        "product": info.product,
        "used": device.binding is not None and not device.error,
        "node_id": device.node_id,
        "entry": device.binding.name if device.binding is not None else None,
        "error": device.error or None,
    }


# A mapping error names the config line it comes from: `file:line: key: message`.
CONFIG_LINE = re.compile(r"^(?P<file>.+?):(?P<line>\d+): (?P<key>[^\s:]+): (?P<message>.+)$")


def bind_problem(device: BoundDevice) -> dict[str, Any]:
    """A device the config does not fit: at the config line when the error names one (for
    an editor to jump to), else at the recording; `recording` says which device it was."""
    match = CONFIG_LINE.match(device.error)
    if match is None:
        problem = Problem(device.info.path, None, None, device.error)
    else:
        problem = Problem(match["file"], int(match["line"]), match["key"], match["message"])
    return {**problem_record(problem), "recording": device.info.path}


def run(args: argparse.Namespace) -> int:
    document: dict[str, Any] = {"config": args.config, "ok": True, "problems": []}
    try:
        config = load_or_default(args.config)
    except ConfigError as exc:
        document["ok"] = False
        document["problems"] = [problem_record(p) for p in exc.problems]
        print(json.dumps(document, indent=2))
        return 2
    document["outputs"] = output_records(config)
    if args.replay:
        devices, problems = bind_replay(compile_mapping(config), args.replay)
        document["replay"] = [device_record(d) for d in devices]
        document["problems"] = [bind_problem(d) for d in devices if d.error] + [
            problem_record(Problem(args.replay, None, None, p), "warning") for p in problems
        ]
        document["ok"] = not any(d.error for d in devices)
    print(json.dumps(document, indent=2))
    return 0 if document["ok"] else 2
