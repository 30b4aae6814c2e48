"""An output steps only the nodes it reads (docs/DESIGN.md, "Node state: one step per
period"): `NodeTable.step_if_due(node_ids)` steps those nodes (and the nodes of the switches
their throttle cuts follow), the others keep the view of their last step; a change of
devices steps every node. Whatever nodes the steps asked for, the frames of the nodes asked
for are those of a table that steps every node every time."""

from __future__ import annotations

import random
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from daemon_harness import StickState
from test_node_table_driver import BINDING, LAYOUT, info

from usb2rc.config.channel_ref import ChannelRef
from usb2rc.config.controls_model import SwitchConfig, ThrottleCut
from usb2rc.configfile import Config, OutputConfig
from usb2rc.daemon import Daemon
from usb2rc.hid.reader import ReaderRecord
from usb2rc.hid.replay import ReplayBackend
from usb2rc.lines.driver import LineDriver, nodes_read_by
from usb2rc.nodes.guard import REST_S
from usb2rc.nodes.mapping import ChannelSource, MixLine
from usb2rc.nodes.step import BASE_PERIOD_S, TapLatch
from usb2rc.nodes.table import NodeTable
from usb2rc.protocols.channels import nodes_read
from usb2rc.protocols.registry import PROTOCOLS

# every protocol, on a port it can be built on without a far end
PORTS = {name: "udpout:127.0.0.1:9" if name == "mavlink" else "loop://" for name in PROTOCOLS}


@dataclass
class Clock:
    now: float = 100.0

    def __call__(self) -> float:
        return self.now


class CountingSource:
    """A reader's record, and how often the step pulled it."""

    def __init__(self, record: ReaderRecord) -> None:
        self.record = record
        self.pulls = 0

    def pull(self) -> None:
        self.pulls += 1


def record(state: StickState, reports: int, at: float) -> ReaderRecord:
    """A reader's record of `state`; its buttons, when any, pressed by this report."""
    decoder = LAYOUT.make_decoder()
    decoder.feed(state.report())
    presses = (state.buttons,) if state.buttons else ()
    return ReaderRecord(decoder.state(), reports, 0, at, presses, reports if presses else 0)


def table_of(nodes: int, clock: Clock) -> tuple[NodeTable, list[CountingSource]]:
    table = NodeTable(clock=clock)
    sources = []
    for node_id in range(nodes):
        source = CountingSource(record(StickState(), 1, clock.now))
        table.add_device(node_id, info(f"k{node_id}", f"1-{node_id}"), BINDING, source, "J")
        sources.append(source)
    table.step_if_due()
    clock.now += REST_S + BASE_PERIOD_S  # at rest that long: live
    assert not any(frame.failsafe for frame in table.step_if_due().frames)
    return table, sources


def test_a_step_of_some_nodes_leaves_the_others_as_their_last_step_left_them() -> None:
    clock = Clock()
    table, sources = table_of(2, clock)
    before = table.step_if_due()
    clock.now += BASE_PERIOD_S
    for n, source in enumerate(sources):
        source.record = record(StickState(x=1000 * (n + 1)), 2, clock.now)
    pulls = [source.pulls for source in sources]
    after = table.step_if_due(frozenset({0}))
    assert after.nodes[0].frame.axes != before.nodes[0].frame.axes  # stepped
    assert after.nodes[1] is before.nodes[1]  # its view from the step before
    assert [s.pulls - p for s, p in zip(sources, pulls, strict=True)] == [1, 0]
    every = table.step_if_due()
    assert every.nodes[1].frame.axes != before.nodes[1].frame.axes
    assert every.nodes[0] is after.nodes[0]  # stepped on these records in this period


def test_a_change_of_devices_steps_every_node() -> None:
    clock = Clock()
    table, _ = table_of(2, clock)
    table.step_if_due()
    table.add_device(2, info("k2", "1-2"), BINDING, CountingSource(record(StickState(), 1, 0)), "J")
    snapshot = table.step_if_due(frozenset({0}))
    assert [view.frame.node_id for view in snapshot.nodes] == [0, 1, 2]


def test_a_throttle_cut_steps_the_node_of_the_switch_it_follows() -> None:
    clock = Clock()
    table, sources = table_of(2, clock)
    gear = SwitchConfig("gear", "toggle", (ChannelRef(1, "button", 1, "node1.button1"),))
    table.set_controls([gear], [ThrottleCut("gear", ChannelRef(0, "axis", 2, "node0.z"))])
    table.step_if_due()
    clock.now += BASE_PERIOD_S
    pulls = sources[1].pulls
    table.step_if_due(frozenset({0}))
    assert sources[1].pulls == pulls + 1


def test_the_frames_asked_for_are_those_of_a_table_that_steps_every_node() -> None:
    """Random records, random sets of nodes asked for, taps included: each node asked for
    has the frame a table stepping every node gives, on the same records at the same time."""
    rng = random.Random(7)
    clocks = Clock(), Clock()
    (partial, sources), (full, references) = table_of(3, clocks[0]), table_of(3, clocks[1])
    latches = {frozenset({0}): TapLatch(), frozenset({1, 2}): TapLatch(), None: TapLatch()}
    reference_latches = {key: TapLatch() for key in latches}
    for reports in range(2, 400):
        for clock in clocks:
            clock.now += rng.choice((0.0, 0.001, BASE_PERIOD_S))
        for n in range(3):
            if rng.random() < 0.6:
                state = StickState(x=rng.randrange(16384), buttons=rng.randrange(4))
                sources[n].record = references[n].record = record(state, reports, clocks[0].now)
        asked = rng.choice(list(latches))
        got = latches[asked].frames(partial.step_if_due(asked), asked)
        want = reference_latches[asked].frames(full.step_if_due(), asked)
        assert got == want


def testnodes_read_by_by_channels_mixes_and_unresolved_switches() -> None:
    x0 = ChannelSource(0, "axis", 0)
    b3 = ChannelSource(3, "button", 1)
    rate = ChannelSource(5, "switch", -1, name="switch.rate")
    mix = ChannelSource(-1, "mix", 0, mix=(MixLine(b3, 1.0, 0.0, None, (rate, (1.0, 0.5))),))
    assert nodes_read([x0, b3]) == {0, 3}
    assert nodes_read([x0, mix]) == {0, 3, 5}
    assert nodes_read([ChannelRef(-1, "switch", -1, "switch.gear")]) is None


class _Session:
    """What `nodes_read_by` asks of a driver's session."""

    def __init__(self, reads: frozenset[int] | None) -> None:
        self.reads = reads


def _driver(reads: frozenset[int] | None) -> LineDriver:
    """A driver (a compiled function takes only a real one) over a session reading `reads`."""
    link: Any = SimpleNamespace(url="loop://")
    session: Any = _Session(reads)
    return LineDriver("out", link, session, NodeTable().step_if_due, 0.02)


def test_outputs_due_together_step_the_nodes_any_of_them_reads() -> None:
    crsf, sbus, c2 = _driver(frozenset({0})), _driver(frozenset({1, 2})), _driver(None)
    assert nodes_read_by([crsf, sbus]) == {0, 1, 2}
    assert nodes_read_by([crsf, c2]) is None


def test_each_protocols_output_reads_the_nodes_of_its_channels(tmp_path: Path) -> None:
    """Built as the daemon builds them: a channel output reads its channels' nodes, C2-16B
    every node (it sends them all)."""
    channels = (ChannelRef(0, "axis", 0, "node0.x"), ChannelRef(2, "axis", 1, "node2.y"))
    outputs = [
        OutputConfig(protocol=name, port=port, channels=channels)
        for name, port in PORTS.items()
        if name != "c2-16b"
    ]
    outputs.append(OutputConfig(protocol="c2-16b", port="loop://"))
    daemon = Daemon(Config(outputs=tuple(outputs)), ReplayBackend(tmp_path))
    reads = {out.config.protocol: out.driver.session.reads for out in daemon.outputs}
    assert reads == {name: None if name == "c2-16b" else {0, 2} for name in PORTS}
