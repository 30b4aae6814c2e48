"""The node step's steady path: compiled (`usb2rc/nodes/_steady.c`), optional.

Python decides, C moves data. Most steps of a node decide nothing new: its devices report,
and it either waits in the neutral guard (every guarded axis moving, none resting yet) or
is live with nothing held over. The node table's Python step (`nodes.table._Node.step`)
is the one home of every decision; after each, `plan_for` compiles what the node's next
steps need (the guard's runs and the axis functions they read, the reasons' texts), and
`step` runs the compiled path on it: the same views and the same state written back as
the Python step, or None, before anything changed, when the node is not steady (a rest
begins, a device goes silent, a gate opens, anything the plan does not cover). The Python
step then runs and compiles the next plan.

Where the module is not built, or is switched off (`usb2rc.hid.speedups.PURE_PYTHON_ENV`,
one switch for every C loop), every step is the Python one. tests/test_steady.py holds the
two to the same snapshots and state, step after step.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from types import ModuleType
from typing import Any, Protocol

from usb2rc.hid import reader, speedups
from usb2rc.nodes import guard, scaling, silence
from usb2rc.nodes.binding import NodeInputs
from usb2rc.nodes.step import DeviceView, NodeFrame, NodeView

try:
    from usb2rc.nodes import _steady as _built
except ImportError:  # pragma: no cover - a machine where it could not be built
    _built = None  # type: ignore[assignment]


class PlannedNode(Protocol):
    """A node of the table (`nodes.table._Node`), as a plan reads it."""

    @property
    def attached(self) -> Sequence[Any]: ...
    @property
    def expected(self) -> Mapping[str, Any]: ...


# (layout, node, its devices, one (binding, runs, kind, suffix) per device, [its last view]);
# a run: (first, last, text, the slot's function or None, slot, a centre axis, unsigned)
Plan = tuple[int, Any, tuple[Any, ...], tuple[tuple[Any, ...], ...], list[NodeView]]

# the fields the C path reads by position, and the views it builds (all their fields)
_READ: dict[str, tuple[Any, tuple[str, ...]]] = {
    "record": (reader.ReaderRecord, ("state", "reports", "at", "press_serial",
                                     "refused_in_a_row", "bad_spells", "repeats")),
    "view": (NodeView, ("frame", "devices", "base_axes", "base_unsigned")),
    "frame": (NodeFrame, ("node_id", "failsafe")),
    "device": (DeviceView, ("inputs", "live")),
    "inputs": (NodeInputs, ("axes", "group1", "group2", "handover", "low_battery")),
}  # fmt: skip
_BUILT: dict[str, tuple[Any, tuple[str, ...]]] = {
    "device": (DeviceView, ("device_id", "binding", "inputs", "live", "known", "record",
                            "trims", "held_over", "counts_from")),
    "view": (NodeView, ("frame", "devices", "base_axes", "base_unsigned", "waiting_for",
                        "overrides")),
    "frame": (NodeFrame, ("node_id", "failsafe", "axes", "group1", "group2", "unsigned_slots",
                          "handover", "low_battery", "switches", "pressed",
                          "pressed_switches")),
}  # fmt: skip


def _configured(module: ModuleType) -> ModuleType | None:
    """The module, told the classes it builds and where it reads; None if those are not
    the fields it was written for (a field added to a view: the Python step runs)."""
    if any(cls._fields != names for cls, names in _BUILT.values()):
        return None
    fields = {
        f"{kind}.{name}": cls._fields.index(name)
        for kind, (cls, names) in _READ.items()
        for name in names
    }
    fields.update({f"sizes.{kind}": len(names) for kind, (_, names) in _BUILT.items()})
    limits = {
        "bad_reports_limit": float(reader.BAD_REPORTS_LIMIT),
        "streaming_after": float(silence.STREAMING_AFTER),
        "min_silence_s": silence.MIN_SILENCE_S,
        "silence_intervals": float(silence.SILENCE_INTERVALS),
        "rate_window_s": silence.RATE_WINDOW_S,
        "fixed_s": guard.FIXED_S,
        "end_margin": guard.END_MARGIN,
    }
    module.configure((DeviceView, NodeView, NodeFrame), fields, limits)
    return module


_compiled = _configured(_built) if _built is not None and speedups.compiled() else None


def compiled() -> ModuleType | None:
    """The compiled steady path, or None: not built, switched off, or not for these views."""
    return _compiled


def status() -> str:
    """One line for the log at start: which path the node steps take, and why."""
    if _built is None:
        return (
            "node step's C path not built here: every step runs in Python (the same "
            "values, more CPU); `sudo apt install gcc python3-dev` and reinstall usb2rc"
        )
    if speedups.compiled() is None:
        return f"node step's C path built but switched off ({speedups.PURE_PYTHON_ENV})"
    if _compiled is None:
        return "node step's C path built for other views than these: reinstall usb2rc"
    return "node step: steady nodes compiled"


def plan_for(
    node: PlannedNode, view: NodeView, layout: int, last: Plan | None = None
) -> Plan | None:
    """What the compiled path needs for the node's next steps, from the Python step that
    made `view` (the devices' table layout `layout`); None where it never applies: no
    device, an expected entry (its failsafe values under the devices), a trim switch.
    The `last` plan serves again, with this view, while the layout is the same (a node the
    compiled path hands back step after step, as one with a button held over, costs no new
    plan each time)."""
    if last is not None and last[0] == layout:
        last[4][0] = view
        return last
    attached = tuple(node.attached)
    if not attached or node.expected or any(a.binding.trim_switches for a in attached):
        return None
    devices = []
    for a in attached:
        binding = a.binding
        functions = dict(binding.guarded_functions)  # the last one of a slot, as `apply`
        rests = binding.guard
        runs = tuple(
            (
                low,
                high,
                text,
                fn,
                slot,
                axis.arm == "centre",
                axis.unsigned,
                scaling.linear_terms(fn),
            )
            for axis, (slot, low, high, text) in zip(rests.axes, rests.wire_runs, strict=True)
            for fn in [functions.get(slot)]
        )
        name = a.info.product or "device"
        devices.append((binding, runs, f"guard {name}", f" ({name})"))
    return (layout, node, attached, tuple(devices), [view])


def step(plan: Plan, records: Sequence[Any], now: float) -> NodeView | None:
    """The node's step on the compiled path; None: not steady (the Python step decides)."""
    assert _compiled is not None
    view: NodeView | None = _compiled.step(plan, tuple(records), now)
    return view
