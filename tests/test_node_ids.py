"""NodeIdAllocator: lowest free first, pins reserved, re-plug gets the old ID back."""

from __future__ import annotations

import pytest

from usb2rc.hid.backend import DeviceInfo
from usb2rc.hid.hotplug import sort_by_port_path
from usb2rc.nodes.node_ids import MAX_NODE_ID, NodeIdAllocator, NodeIdError

_plugs = iter(range(10**6))


def dev(port: str, serial: str = "", vid: int = 0x044F, pid: int = 0xB10A) -> DeviceInfo:
    """A fresh plug: every call is a new key, as a real re-plug is."""
    n = next(_plugs)
    return DeviceInfo(f"/dev/hidraw{n}", f"/dev/hidraw{n}", vid, pid, serial, port_path=port)


def test_lowest_free_in_port_path_order() -> None:
    alloc = NodeIdAllocator()
    present = sort_by_port_path([dev("1-1.10"), dev("1-1.2"), dev("1-1.3")])
    assert [d.port_path for d in present] == ["1-1.2", "1-1.3", "1-1.10"]
    assert [alloc.assign(d) for d in present] == [0, 1, 2]


def test_assign_is_stable_while_plugged() -> None:
    alloc = NodeIdAllocator()
    a = dev("1-1")
    assert alloc.assign(a) == alloc.assign(a) == 0


def test_released_id_is_reused_lowest_first() -> None:
    alloc = NodeIdAllocator()
    a, b, c = dev("1-1"), dev("1-2"), dev("1-3")
    assert [alloc.assign(x) for x in (a, b, c)] == [0, 1, 2]
    alloc.release(b)
    assert alloc.assign(dev("2-9")) == 1


def test_replug_same_port_gets_old_id() -> None:
    alloc = NodeIdAllocator()
    a, b = dev("1-1"), dev("1-2")
    alloc.assign(a)
    alloc.assign(b)
    alloc.release(a)
    alloc.release(b)
    assert alloc.assign(dev("1-2")) == 1
    assert alloc.assign(dev("1-1")) == 0


def test_replug_same_serial_on_another_port_gets_old_id() -> None:
    alloc = NodeIdAllocator()
    a = dev("1-1", serial="S1")
    b = dev("1-2", serial="S2")
    alloc.assign(a)
    alloc.assign(b)
    alloc.release(a)
    alloc.release(b)
    assert alloc.assign(dev("1-2", serial="S1")) == 0  # identity wins over the port
    assert alloc.assign(dev("1-1", serial="S2")) == 1


def test_empty_serial_does_not_match_other_devices() -> None:
    alloc = NodeIdAllocator()
    a = dev("1-1")
    alloc.assign(a)
    alloc.release(a)
    assert alloc.assign(dev("1-5")) == 0  # lowest free, not a memory match
    assert alloc.assign(dev("1-1")) == 1  # its remembered 0 is taken now


def test_remembered_id_taken_meanwhile_gives_lowest_free() -> None:
    alloc = NodeIdAllocator()
    a = dev("1-1", serial="A")
    alloc.assign(a)
    alloc.release(a)
    alloc.assign(dev("1-2", serial="B"))  # takes 0
    assert alloc.assign(dev("1-1", serial="A")) == 1


def test_pins_are_reserved_from_the_start() -> None:
    alloc = NodeIdAllocator(pinned={0, 2})
    assert alloc.assign(dev("1-1")) == 1
    assert alloc.assign(dev("1-2")) == 3
    assert alloc.assign(dev("1-3"), pinned=0) == 0
    assert alloc.assign(dev("1-4"), pinned=0) == 0  # several devices may feed one node


def test_late_pin_is_reserved_from_then_on() -> None:
    alloc = NodeIdAllocator()
    assert alloc.assign(dev("1-1"), pinned=1) == 1
    assert alloc.assign(dev("1-2")) == 0
    assert alloc.assign(dev("1-3")) == 2


def test_replug_of_pinned_device_keeps_pin() -> None:
    alloc = NodeIdAllocator(pinned={7})
    a = dev("1-1", serial="P")
    assert alloc.assign(a, pinned=7) == 7
    alloc.release(a)
    assert alloc.assign(dev("1-1", serial="P"), pinned=7) == 7
    assert alloc.assign(dev("1-2")) == 0


def test_range_and_exhaustion() -> None:
    with pytest.raises(NodeIdError):
        NodeIdAllocator(pinned={255})
    alloc = NodeIdAllocator()
    with pytest.raises(NodeIdError):
        alloc.assign(dev("1-1"), pinned=-1)
    for i in range(MAX_NODE_ID + 1):
        assert alloc.assign(dev(f"9-{i}")) == i
    with pytest.raises(NodeIdError):
        alloc.assign(dev("9-999"))
