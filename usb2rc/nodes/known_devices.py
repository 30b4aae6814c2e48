"""The device database: where the axes of known flight gear rest (package data devices.yaml).

With zero config the neutral guard knows an axis only by its usage (guard.default_arm): X, Y
and Rz of a stick at the centre. Rudder pedals (toe brakes at an end), a throttle on HID Z
and a gamepad's loose thumb sticks need more: `lookup(vid, pid)` gives the entry of a known
device, each axis's role and where it rests (`arm`), with the public source of both. A
config axis with `arm:` overrides it (docs/CONFIG.md, "Neutral guard").

The file is read once, on first use; a malformed entry raises KnownDevicesError naming the
entry (the file ships with usb2rc: tests/test_known_devices.py reads every entry).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from importlib import resources
from typing import Any

import yaml

from usb2rc.config.model import ARM_CHOICES
from usb2rc.hid.usages import usage_from_name, usage_name
from usb2rc.nodes.guard import GuardedAxis, default_arm, default_tolerance, normalize_arm

DATA_FILE = "devices.yaml"
KINDS = ("gamepad", "joystick", "throttle", "pedals", "hotas")
ENTRY_KEYS = {"vid", "pid", "name", "kind", "source", "axes"}
AXIS_KEYS = {"role", "arm", "why"}


class KnownDevicesError(ValueError):
    pass


@dataclass(frozen=True)
class KnownAxis:
    usage: int
    role: str  # "rudder", "throttle", "left toe brake"
    arm: str  # centre, low, high, any (config.model.ARM_CHOICES, normalized)
    why: str = ""  # the source of `arm` when it is not the entry's

    @property
    def label(self) -> str:
        """ "Z (throttle)": for what the guard waits for."""
        return f"{usage_name(self.usage)} ({self.role})"


@dataclass(frozen=True)
class KnownDevice:
    vid: int
    pid: int
    name: str
    kind: str  # KINDS
    source: str
    axes: tuple[KnownAxis, ...]

    def axis(self, usage: int | None) -> KnownAxis | None:
        return next((a for a in self.axes if a.usage == usage), None)

    def describe(self) -> list[str]:
        """For `describe --known`: the ID, name and kind, then one line per axis."""
        lines = [f"{self.vid:04x}:{self.pid:04x}  {self.name} ({self.kind})"]
        for a in self.axes:
            why = f"  [{a.why}]" if a.why else ""
            lines.append(f"    {usage_name(a.usage):<8} {a.role:<26} arm {a.arm}{why}")
        lines.append(f"    source: {self.source}")
        return lines


def lookup(vid: int, pid: int) -> KnownDevice | None:
    """The database entry of the device with this vid:pid, or None."""
    return _by_id().get((vid, pid))


def all_devices() -> tuple[KnownDevice, ...]:
    """Every entry, in the file's order."""
    return _load()


@functools.cache
def _by_id() -> dict[tuple[int, int], KnownDevice]:
    return {(d.vid, d.pid): d for d in _load()}


@functools.cache
def _load() -> tuple[KnownDevice, ...]:
    text = (resources.files("usb2rc") / "data" / DATA_FILE).read_text(encoding="utf-8")
    return parse_devices(yaml.safe_load(text))


def parse_devices(document: Any) -> tuple[KnownDevice, ...]:
    """The entries of a devices.yaml document; KnownDevicesError names a malformed one."""
    entries = document.get("devices") if isinstance(document, dict) else None
    if not isinstance(entries, list):
        raise KnownDevicesError(f"{DATA_FILE}: needs a `devices:` list")
    devices = tuple(_parse_entry(entry, i) for i, entry in enumerate(entries))
    seen: set[tuple[int, int]] = set()
    for d in devices:
        if (d.vid, d.pid) in seen:
            raise KnownDevicesError(f"{DATA_FILE}: {d.vid:04x}:{d.pid:04x} listed twice")
        seen.add((d.vid, d.pid))
    return devices


def _parse_entry(entry: Any, index: int) -> KnownDevice:
    where = f"{DATA_FILE}: devices[{index}]"
    if not isinstance(entry, dict) or set(entry) != ENTRY_KEYS:
        keys = sorted(entry) if isinstance(entry, dict) else entry
        raise KnownDevicesError(f"{where}: needs exactly {sorted(ENTRY_KEYS)}, has {keys}")
    for key in ("vid", "pid"):
        if not isinstance(entry[key], int) or not 0 <= entry[key] <= 0xFFFF:
            raise KnownDevicesError(f"{where}.{key}: {entry[key]!r} is not a USB ID")
    if entry["kind"] not in KINDS:
        raise KnownDevicesError(f"{where}.kind: {entry['kind']!r} is not one of {KINDS}")
    if not isinstance(entry["axes"], dict) or not entry["axes"]:
        raise KnownDevicesError(f"{where}.axes: needs one entry per HID usage")
    axes = tuple(
        _parse_axis(name, spec, f"{where}.axes.{name}") for name, spec in entry["axes"].items()
    )
    return KnownDevice(
        entry["vid"], entry["pid"], str(entry["name"]), entry["kind"], str(entry["source"]), axes
    )


def _parse_axis(name: str, spec: Any, where: str) -> KnownAxis:
    try:
        usage = usage_from_name(str(name))
    except KeyError:
        raise KnownDevicesError(f"{where}: {name!r} is not a HID usage name") from None
    if not isinstance(spec, dict) or not {"role", "arm"} <= set(spec) or set(spec) - AXIS_KEYS:
        raise KnownDevicesError(f"{where}: needs role and arm (and optionally why)")
    if spec["arm"] not in ARM_CHOICES:
        raise KnownDevicesError(f"{where}.arm: {spec['arm']!r} is not one of {ARM_CHOICES}")
    return KnownAxis(usage, str(spec["role"]), normalize_arm(spec["arm"]), str(spec.get("why", "")))


def guard_axis(
    slot: int,
    label: str,
    usage: int | None,
    application: int,
    known: KnownDevice | None,
    configured: tuple[str | None, float | None] = (None, None),
) -> GuardedAxis | None:
    """The neutral guard of one axis slot (None: not guarded). Where it rests: `arm:` from
    the config (`configured`: arm, arm_tolerance), else the database entry's, else by its
    usage (guard.default_arm); its tolerance: `arm_tolerance:`, else by the device's kind."""
    arm, tolerance = configured
    entry = known.axis(usage) if known is not None else None
    if arm is not None:
        arm = normalize_arm(arm)
    elif entry is not None:
        arm, label = entry.arm, entry.label
    else:
        arm = default_arm(usage, application)
    if arm == "any":
        return None
    if tolerance is None:
        tolerance = default_tolerance(application, known.kind if known is not None else None)
    return GuardedAxis(slot, label, arm, tolerance)
