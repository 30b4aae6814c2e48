"""The node step's compiled steady path (usb2rc.nodes.steady, usb2rc/nodes/_steady.c)
against the Python step: two node tables fed the same reader records at the same times,
one stepping in Python only, give the same snapshots, the same log lines and the same
state (guard, press gate, silence watch, reasons), step after step; and the compiled path
does take the steady steps (a test that it runs at all)."""

from __future__ import annotations

import contextlib
import dataclasses
import os
from collections.abc import Iterator
from typing import Any

import pytest
from daemon_harness import HAT_NULL, T16000M_DESCRIPTOR, RecordSource, StickState
from hypothesis import given, settings
from hypothesis import strategies as st

from usb2rc.configfile import load_config_text
from usb2rc.hid.backend import DeviceInfo
from usb2rc.hid.descriptor import parse_descriptor
from usb2rc.hid.reader import BAD_REPORTS_LIMIT, PRESSES_KEPT, ReaderRecord
from usb2rc.nodes import steady
from usb2rc.nodes.binding import default_binding
from usb2rc.nodes.mapping import compile_mapping
from usb2rc.nodes.table import NodeTable

if steady.compiled() is None:
    if os.environ.get("CI"):
        pytest.fail("the compiled step was not built (setup.py; a C compiler, Python headers)")
    pytest.skip(
        "the compiled step is not built here: every step runs in Python", allow_module_level=True
    )

LAYOUT = parse_descriptor(T16000M_DESCRIPTOR)
BINDING = default_binding(LAYOUT, "T.16000M")  # X, Y, Rz guarded at the centre
INFO = DeviceInfo(key="k", path="k", vid=0x044F, pid=0xB10A, product="T.16000M")
# shaped and inverted axes, a hat and two buttons as axes, a handover button, a battery
CONFIGURED = compile_mapping(
    load_config_text(
        """devices:
  - name: stick
    match: {vid: 0x044f}
    node_id: 0
    axes:
      x: {usage: X, expo: 0.3, deadband: 0.05}
      y: {usage: Y, invert: true}
      rz: {usage: Rz, calibration: {min: 10, center: 120, max: 250}}
      z: {hat: HatSwitch, axis: y}
      aux1: {buttons: [5, 6]}
    handover: {button: 2, destination: 7}
    low_battery: {usage: Slider, below: 10}
""",
        "steady.yaml",
    )
).bind(INFO, LAYOUT)
assert CONFIGURED is not None
NODES = (0, 0, 1)  # two sticks on node 0, one on node 1
BINDINGS = (BINDING, CONFIGURED, BINDING)


@contextlib.contextmanager
def python_only() -> Iterator[None]:
    """The Python step alone (as where the C path is not built), for the calls inside."""
    saved = steady._compiled
    steady._compiled = None
    try:
        yield
    finally:
        steady._compiled = saved


class Stick:
    """A reader's records as DeviceReader publishes them: reports counted, refused ones,
    their runs, the press log, repeats of the report before."""

    def __init__(self) -> None:
        self.decoder = LAYOUT.make_decoder()
        self.record = ReaderRecord(LAYOUT.initial_state(), 0)
        self.last = b""

    def report(self, state: StickState, at: float) -> ReaderRecord:
        r, raw = self.record, state.report()
        before = r.state.buttons if r.reports else 0
        self.decoder.feed(raw)
        new = self.decoder.state()
        pressed = new.buttons & ~before
        presses, serial = r.presses, r.press_serial
        if pressed:
            presses, serial = (*presses, pressed)[-PRESSES_KEPT:], serial + 1
        repeats = r.repeats + (raw == self.last)
        self.last = raw
        self.record = r._replace(
            state=new, reports=r.reports + 1, at=at, presses=presses, press_serial=serial,
            refused_in_a_row=0, repeats=repeats,
        )  # fmt: skip
        return self.record

    def refuse(self) -> ReaderRecord:
        r = self.record
        refused = r.refused_in_a_row + 1
        spells = r.bad_spells + (refused == BAD_REPORTS_LIMIT)
        self.record = r._replace(
            bad_reports=r.bad_reports + 1, refused_in_a_row=refused, bad_spells=spells
        )
        return self.record


def info(k: int, plug: int) -> DeviceInfo:
    return DeviceInfo(key=f"k{k}.{plug}", path=f"k{k}.{plug}", vid=0x044F, pid=0xB10A,
                      product=f"Stick {k}", port_path=f"1-{k}")  # fmt: skip


class Pair:
    """Two node tables on the same sources and clock: `compiled` may take the C path."""

    def __init__(self) -> None:
        self.now = 100.0
        self.compiled = NodeTable(clock=lambda: self.now)
        self.python = NodeTable(clock=lambda: self.now)
        self.sticks = [Stick() for _ in NODES]
        self.sources = [RecordSource(s.record) for s in self.sticks]
        self.plugs = [0 for _ in NODES]
        self.present = [True for _ in NODES]
        for k in range(len(NODES)):
            self._plug(k)

    def _plug(self, k: int) -> None:
        for table in (self.compiled, self.python):
            binding = BINDINGS[k]
            table.add_device(NODES[k], info(k, self.plugs[k]), binding, self.sources[k], "JOYSTICK")

    def unplug(self, k: int) -> None:
        if self.present[k]:
            self.present[k] = False
            for table in (self.compiled, self.python):
                table.remove_device(f"k{k}.{self.plugs[k]}")

    def replug(self, k: int) -> None:
        if not self.present[k]:
            self.present[k], self.plugs[k] = True, self.plugs[k] + 1
            self.sticks[k] = Stick()
            self.sources[k] = RecordSource(self.sticks[k].record)
            self._plug(k)

    def report(self, k: int, state: StickState) -> None:
        self.sources[k].record = self.sticks[k].report(state, self.now)

    def refuse(self, k: int) -> None:
        self.sources[k].record = self.sticks[k].refuse()

    def tick(self, states: list[StickState], dt: float) -> None:
        """Each stick plugged reports its state, `dt` later a step."""
        for k, state in enumerate(states):
            if self.present[k]:
                self.report(k, state)
        self.now += dt
        self.step()

    def step(self, node_ids: frozenset[int] | None = None) -> None:
        """One step of each table (of the nodes `node_ids`, as an output asks; None:
        every node); their results and state compared."""
        with self.compiled._lock:
            changes = self.compiled._step_if_due_locked(node_ids)
        with python_only(), self.python._lock:
            expected = self.python._step_if_due_locked(node_ids)
        assert changes == expected
        assert self.compiled._snapshot == self.python._snapshot
        assert table_state(self.compiled) == table_state(self.python)


def table_state(table: NodeTable) -> list[Any]:
    """What the steps leave in the table, every field the Python step writes."""
    out: list[Any] = []
    for node_id in sorted(table._nodes):
        node = table._nodes[node_id]
        out.append((node_id, node.stepped_reasons, node.logged, table._resting.get(node_id)))
        for a in node.attached:
            rest = dataclasses.asdict(a.rest) | {"record": id(a.rest.record)}
            rest["moved_all_of"] = a.rest.moved_all_of is a.binding.guard
            out.append((
                a.present, a.armed, a.waiting, a.bad_spells_seen, a.silent_since,
                a.silence_news, a.last_inputs, a.trim_serial, rest,
                dataclasses.asdict(a.gate), dataclasses.asdict(a.silence),
            ))  # fmt: skip
    return out


# near the centre (the guard decides there) and anywhere
COORD = st.one_of(st.sampled_from([8192, 8191, 8200, 7400, 9000, 0, 16383]), st.integers(0, 16383))
STATES = st.builds(
    StickState, x=COORD, y=COORD, rz=st.sampled_from([128, 127, 0, 255, 120, 5]),
    slider=st.sampled_from([128, 0, 20, 255]), buttons=st.sampled_from([0, 0, 0, 1, 2, 3, 48]),
    hat=st.sampled_from([HAT_NULL, 0, 4]),
)  # fmt: skip
DEVICE = st.integers(0, len(NODES) - 1)
TICK = st.sampled_from([0.001, 0.004, 0.004, 0.01, 0.02])
OPS = st.lists(
    st.one_of(
        # every stick reports, then a step: mostly this (the steady steps come from it)
        st.tuples(st.just("fly"), st.lists(STATES, min_size=3, max_size=3), TICK),
        # every stick near its centre for a while (its node arms), buttons as given
        st.tuples(st.just("rest"), st.integers(1, 20), st.sampled_from([0, 0, 1, 2])),
        st.tuples(st.just("same"), TICK),  # the reports before, again (streaming sticks)
        st.tuples(st.just("refuse"), DEVICE, st.integers(1, BAD_REPORTS_LIMIT + 2)),
        st.tuples(st.just("wait"), st.sampled_from([0.06, 0.3, 1.2])),
        st.tuples(st.just("unplug"), DEVICE),
        st.tuples(st.just("replug"), DEVICE),
        # a step of the nodes one output reads, `dt` after the last reports
        st.tuples(st.just("some"), st.sampled_from([frozenset({0}), frozenset({1})]), TICK),
    ),
    max_size=60,
)


def play(pair: Pair, ops: list[Any]) -> None:
    last = [StickState() for _ in NODES]
    for op in ops:
        kind = op[0]
        if kind == "fly":
            last = op[1]
            pair.tick(last, op[2])
        elif kind == "rest":
            for i in range(op[1]):
                last = [StickState(x=8192 + i % 3, buttons=op[2]) for _ in NODES]
                pair.tick(last, 0.004)
        elif kind == "same":
            pair.tick(last, op[1])
        elif kind == "refuse":
            for _ in range(op[2]):
                pair.refuse(op[1])
            pair.step()
        elif kind == "wait":
            pair.now += op[1]
            pair.step()
        elif kind == "unplug":
            pair.unplug(op[1])
            pair.step()
        elif kind == "replug":
            pair.replug(op[1])
            pair.step()
        elif kind == "some":
            pair.now += op[2]
            pair.step(op[1])


@settings(max_examples=300, deadline=None)
@given(OPS)
def test_the_compiled_path_steps_as_the_python_step(ops: list[Any]) -> None:
    play(Pair(), ops)


def counting(monkeypatch: pytest.MonkeyPatch) -> dict[str, int]:
    """How many steps the compiled path took (a view) and handed back (None), and how
    many of its frames had a handover and a low battery."""
    counts = {"taken": 0, "declined": 0, "handover": 0, "low battery": 0}
    real = steady.compiled()
    assert real is not None

    class Counted:
        """The C module `steady.step` calls (a compiled module's own functions cannot be
        swapped; the module it reads at each step can), its steps counted."""

        def __getattr__(self, name: str) -> Any:
            return getattr(real, name)

        def step(self, *args: Any) -> Any:
            view = real.step(*args)
            counts["taken" if view is not None else "declined"] += 1
            if view is not None:
                counts["handover"] += view.frame.handover is not None
                counts["low battery"] += view.frame.low_battery
            return view

    monkeypatch.setattr(steady, "_compiled", Counted())
    return counts


def test_a_waiting_node_and_a_live_one_take_the_compiled_path(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Sticks that keep moving (every guarded axis) wait in the guard; once they rest and
    go live, they fly: both are steady, step after step, and the views are the Python
    step's (a handover button and a low battery among them)."""
    assert steady.status() == "node step: steady nodes compiled"
    counts = counting(monkeypatch)
    pair = Pair()
    moving = [
        StickState(
            x=2000 + 500 * (i % 7), y=14000 - 300 * (i % 5), rz=(0, 255, 30)[i % 3],
            buttons=(0, 1, 3, 2)[i % 4], hat=(HAT_NULL, 0)[i % 2],
        )
        for i in range(40)
    ]  # fmt: skip
    for state in moving:
        for k in range(len(NODES)):
            pair.report(k, state)
        pair.now += 0.004
        pair.step()
    assert all(frame.failsafe for frame in pair.compiled._snapshot.frames)
    waiting_taken = counts["taken"]
    assert waiting_taken > 60  # 2 nodes x 40 steps, the first ones and the new plans aside
    for i in range(60):  # at rest, then flown gently: the handover, a low battery
        flown = i > 30
        state = StickState(
            x=8192 + flown * 40 * (i % 9), y=8192, buttons=flown * (i % 3 == 0) * 2,
            slider=(128, 5)[flown * (i % 2)],
        )  # fmt: skip
        for k in range(len(NODES)):
            pair.report(k, state)
        pair.now += 0.004
        pair.step()
    frames = pair.compiled._snapshot.frames
    assert not any(frame.failsafe for frame in frames)
    assert counts["taken"] - waiting_taken > 40
    assert counts["handover"] and counts["low battery"]


def test_a_silent_stick_and_bad_reports_hand_the_step_back(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """What the compiled path does not decide (a stick gone silent, a run of refused
    reports) goes to the Python step, with the same result."""
    counts = counting(monkeypatch)
    pair = Pair()
    state = StickState(x=3000)
    for _ in range(60):  # streaming: the same report again and again
        for k in range(len(NODES)):
            pair.report(k, state)
        pair.now += 0.01
        pair.step()
    declined = counts["declined"]
    pair.now += 1.0  # silent
    pair.step()
    assert counts["declined"] > declined
    assert "silent" in " ".join(pair.compiled._snapshot.nodes[0].waiting_for)
    for _ in range(BAD_REPORTS_LIMIT):
        pair.refuse(2)
    pair.step()
    assert "refused" in " ".join(pair.compiled._snapshot.nodes[1].waiting_for)


def test_an_axis_never_moved_is_noted_and_named_when_fixed(monkeypatch: pytest.MonkeyPatch) -> None:
    """Sticks moved on X and Y but not on Rz, held at its end: the compiled path notes the
    moves step by step (Rz never moved); from FIXED_S after the plug the Python step says
    Rz may be fixed, with the same views and state on both paths."""
    counts = counting(monkeypatch)
    pair = Pair()
    for i in range(300):  # 6 s at 20 ms
        state = StickState(x=1000 + 700 * (i % 5), y=15000 - 300 * (i % 3), rz=255)
        pair.tick([state] * len(NODES), 0.02)
        if i == 200:  # 4 s: moving, nothing fixed yet
            assert counts["taken"] > 300
            declined = counts["declined"]
            assert not any("fixed" in text for text in pair.compiled._snapshot.nodes[1].waiting_for)
    assert "unmoved at an end" in " ".join(pair.compiled._snapshot.nodes[1].waiting_for)
    assert counts["declined"] > declined
