"""Output reports on the real hidapi (umockdev): a pulled DeviceReader in a process under the
preload library posts states, and the node's other side (the bed's pty master) shows the
bytes hidapi wrote, while the same reader keeps pulling the stick's input reports.

Expected bytes come from hid-tools' reading of the descriptor, not from usb2rc's driver."""

from __future__ import annotations

import json
import textwrap
from collections.abc import Iterator
from typing import Any

import hidtools.hid
import pytest
from umockdev_harness import (
    LED_STICK_DESCRIPTOR,
    FakeStick,
    UsbBed,
    require_umockdev,
    usb_bed,
    wait_until,
)

WAIT_S = 20.0

# The process under the preload library: the daemon's pieces (HidapiBackend, a pulled
# DeviceReader, HidOutputDriver) and a puller thread standing in for the node step.
# Commands on stdin, one JSON line each: {"post": mask, "brightness": x}, {"status": 1},
# {"quit": 1}; every command is answered with the reader's status.
CHILD = textwrap.dedent(
    """
    import json, sys, threading
    from usb2rc.feedback.hid_outputs import HidOutputDriver
    from usb2rc.hid.outputs import OutputState
    from usb2rc.hid.descriptor import parse_descriptor
    from usb2rc.hid.hidapi_backend import HidapiBackend
    from usb2rc.hid.reader import DeviceReader

    backend = HidapiBackend()
    (info,) = [i for i in backend.enumerate() if i.vid == 0x1209]
    device = backend.open(info)
    driver = HidOutputDriver.from_descriptor(device.report_descriptor())
    decoder = parse_descriptor(device.report_descriptor()).make_decoder()
    reader = DeviceReader(device, decoder, lambda r, c: None, pulled=True)
    reader.start()
    done = threading.Event()

    def pull():
        while not done.wait(0.004):
            reader.pull()

    puller = threading.Thread(target=pull)
    puller.start()

    def status():
        out = reader.outputs
        return {"reports": reader.record.reports, "values": list(reader.record.state.values),
                "written": out.written, "refused": out.refused, "error": out.last_error,
                "shown": None if out.shown is None else out.shown.indicators,
                "bus": info.bus, "hidraw": info.hidraw}

    print(json.dumps(status()), flush=True)
    for line in sys.stdin:
        cmd = json.loads(line)
        if "post" in cmd:
            state = OutputState(cmd["post"], (("brightness", cmd["brightness"]),))
            reader.post_output(driver, state)
        if "quit" in cmd:
            break
        print(json.dumps(status()), flush=True)
    done.set()
    puller.join()
    reader.stop()
    reader.join(10)
    print(json.dumps(status()), flush=True)
    """
)


class Child:
    def __init__(self, bed: UsbBed) -> None:
        self.proc = bed.python(CHILD)
        self.first = self._reply()

    def _reply(self) -> dict[str, Any]:
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if not line:
            raise AssertionError(f"the child ended (exit {self.proc.wait()})")
        return dict(json.loads(line))

    def ask(self, **cmd: Any) -> dict[str, Any]:
        assert self.proc.stdin is not None
        self.proc.stdin.write(json.dumps(cmd) + "\n")
        self.proc.stdin.flush()
        return self._reply()

    def close(self) -> dict[str, Any] | None:
        try:
            return self.ask(quit=1) if self.proc.poll() is None else None
        finally:
            self.proc.kill()
            self.proc.wait()


@pytest.fixture
def bed() -> Iterator[UsbBed]:
    require_umockdev()
    with usb_bed() as tb:
        yield tb


def expected_report(mask: int, brightness: int) -> bytes:
    """Report 2 as hid-tools fills it: its 1-bit outputs from `mask` in descriptor order,
    LED Intensity = brightness (constants zero)."""
    rdesc = hidtools.hid.ReportDescriptor.from_bytes(list(LED_STICK_DESCRIPTOR))
    report = rdesc.output_reports[2]
    data = [2] + [0] * (report.size - 1)
    bit = 0
    for f in report.fields:
        if f.is_const:
            continue
        if f.size == 1:
            f.fill_values(data, [mask >> bit & 1])
            bit += 1
        else:
            f.fill_values(data, [brightness])
    return bytes(data)


def input_report(x: int) -> bytes:
    return bytes([1]) + x.to_bytes(2, "little") + (2048).to_bytes(2, "little") + b"\x00"


def read(child: Child, x: int, reports_before: int) -> bool:
    """The reader has read a report since `reports_before`, and its X is `x`."""
    status = child.ask(status=1)
    return bool(status["reports"] > reports_before and status["values"][0] == x)


def test_posted_states_reach_the_node_while_reads_go_on(bed: UsbBed) -> None:
    node = bed.add(FakeStick("1-3", 0x1209, 0x0001, LED_STICK_DESCRIPTOR, "LED stick"))
    child = Child(bed)
    try:
        assert child.first["hidraw"] == node and child.first["bus"] == "usb"
        received = bytearray()

        def arrived(n: int) -> bytes | None:
            received.extend(bed.written(node))
            return bytes(received) if len(received) >= n else None

        x = 100
        for mask, level in ((0b1000_0101, 1.0), (0b0111_1010, 0.0), (0b1, 0.5)):
            before = len(received)
            child.ask(post=mask, brightness=level)
            want = expected_report(mask, round(level * 255))
            # the input goes on meanwhile: each report reaches the reader's state
            for _ in range(3):
                x += 37
                reports = child.ask(status=1)["reports"]
                bed.report(node, input_report(x))
                wait_until(lambda x=x, r=reports: read(child, x, r), WAIT_S, f"X={x} read")
            got = wait_until(lambda b=before, w=want: arrived(b + len(w)), WAIT_S, "the write")
            assert got[before:] == want
        final = child.close()
        assert final is not None
        assert (final["written"], final["refused"], final["shown"]) == (3, 0, 0b1)
        assert bed.written(node) == b""  # nothing more than the three
    finally:
        child.close()
