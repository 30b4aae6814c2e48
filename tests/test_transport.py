"""SerialLink: a slow or failing open never blocks the caller (the driver's tick)."""

from __future__ import annotations

import os
import socket
import threading

import serial

from usb2rc.lines import serial_link as transport
from usb2rc.lines.driver import LineDriver
from usb2rc.lines.link import LineEvent
from usb2rc.lines.serial_link import SOCKET_SEND_BUFFER, SerialLink
from usb2rc.protocols.c2_16b.engine import C2Settings
from usb2rc.protocols.c2_16b.session import C2Session


def c2_driver(link: SerialLink, table) -> LineDriver:
    session = C2Session("test", C2Settings(version="0.1.0"))
    return LineDriver("test", link, session, table.step_if_due, 0.02)


def test_a_slow_open_runs_aside_and_is_reported_once(monkeypatch):
    release = threading.Event()
    entered = threading.Event()
    real_open = serial.serial_for_url

    def slow_open(url, **kwargs):
        entered.set()
        assert release.wait(10), "never released"
        return real_open("loop://", **kwargs)

    monkeypatch.setattr(transport.serial, "serial_for_url", slow_open)
    link = SerialLink("slow://", reopen_interval_s=0.0)
    assert link.try_open() is False  # returns at once although the open is still going on
    assert entered.wait(10)
    assert not link.is_open and link.try_open() is False  # one opener at a time
    release.set()
    link._opener.join(10)
    assert link.is_open
    assert link.line_event() is LineEvent.OPENED and link.line_event() is None
    assert link.write(b"H-").sent == 2 and link.stats.opens == 1
    link.close()


def test_a_failing_open_is_logged_once_with_what_to_do(monkeypatch, caplog):
    def missing(url, **kwargs):
        raise serial.SerialException(f"[Errno 2] could not open port {url}: No such file")

    monkeypatch.setattr(transport.serial, "serial_for_url", missing)
    link = SerialLink("/dev/ttyUSB9", reopen_interval_s=0.0)
    assert link.open_now() is False
    for _ in range(3):
        link.try_open()
        link._opener.join(10)
    errors = [r.message for r in caplog.records if "ttyUSB9" in r.message]
    assert len(errors) == 1 and "--port" in errors[0]
    assert link.line_event() is None


class PausingTable:
    """A NodeTable whose next `step_if_due` stops until the test lets it go on: the writer
    thread is held in the middle of a tick, at the point of the test's choosing."""

    def __init__(self, table) -> None:
        self.table = table
        self.in_collect = threading.Event()
        self.go_on = threading.Event()
        self.pause_next = False

    def __getattr__(self, name):
        return getattr(self.table, name)

    def step_if_due(self, node_ids=None):
        if self.pause_next:
            self.pause_next = False
            self.in_collect.set()
            assert self.go_on.wait(10), "never let go on"
        return self.table.step_if_due(node_ids)


def test_a_port_opened_in_the_middle_of_a_tick_carries_nothing_before_the_startup(monkeypatch):
    """The bad interleaving of issue 11: the opener publishes the new port while the writer
    is in the middle of a tick (after it looked at the line, before it writes). That tick
    must not write on the new port; the next one starts it with `8` and the connect
    sequence, and no `>` comes before them."""
    from daemon_harness import StickState
    from test_node_table_driver import BINDING, Source, info

    from usb2rc.nodes.table import NodeTable
    from usb2rc.protocols.c2_16b import codec as c2_16b

    release_open = threading.Event()
    ports = []
    real_open = serial.serial_for_url

    def held_open(url, **kwargs):
        assert release_open.wait(10), "never released"
        ports.append(real_open("loop://", **kwargs))
        return ports[-1]

    monkeypatch.setattr(transport.serial, "serial_for_url", held_open)
    table = PausingTable(NodeTable())
    table.add_device(0, info("k0", "1-1"), BINDING, Source.of(StickState()), "JOYSTICK")
    link = SerialLink("held://", reopen_interval_s=0.0)
    out = c2_driver(link, table)
    table.pause_next = True
    ticking = threading.Thread(target=out.tick)
    ticking.start()  # starts the opener (held), finds no line, then stops in the step
    assert table.in_collect.wait(10)
    release_open.set()
    link._opener.join(10)
    assert link.is_open  # the port is there while the tick is still going on
    table.go_on.set()
    ticking.join(10)
    assert ports[0].out_waiting == 0, "the tick wrote on a port it was not told of"
    for _ in range(3):
        out.tick()
    frames = c2_16b.Decoder().feed(ports[0].read(ports[0].in_waiting))
    names = [
        f.service.service_name if isinstance(f, c2_16b.ServiceFrame) else chr(f.status)
        for f in frames
    ]
    assert names[:5] == ["startup", "connected", "vid-pid", "device-string", "device-type"]
    assert names[5:] == [">"] * 3
    link.close()


def test_a_line_lost_and_reopened_starts_again_with_the_startup_frame(monkeypatch):
    """The RX thread finds the port broken; the writer closes it and opens another, whose
    line starts with `8` and the connect sequence before any `>`."""
    from daemon_harness import StickState
    from test_node_table_driver import BINDING, Source, info

    from usb2rc.nodes.table import NodeTable
    from usb2rc.protocols.c2_16b import codec as c2_16b

    ports = []
    real_open = serial.serial_for_url

    def open_loop(url, **kwargs):
        ports.append(real_open("loop://", **kwargs))
        return ports[-1]

    monkeypatch.setattr(transport.serial, "serial_for_url", open_loop)
    table = PausingTable(NodeTable())
    table.add_device(0, info("k0", "1-1"), BINDING, Source.of(StickState()), "JOYSTICK")
    link = SerialLink("again://", reopen_interval_s=0.0)
    assert link.open_now()
    out = c2_driver(link, table)
    for _ in range(3):
        out.tick()
    link._broken = (ports[0], OSError("gone"))  # what LinkReader records on a read failure
    out.tick()  # the writer closes it ...
    out.tick()  # ... and starts the opener
    link._opener.join(10)
    assert link.is_open and len(ports) == 2
    for _ in range(2):
        out.tick()
    frames = c2_16b.Decoder().feed(ports[1].read(ports[1].in_waiting))
    assert frames[0].service is c2_16b.Service.STARTUP
    first_live = next(i for i, f in enumerate(frames) if getattr(f, "status", 0) == c2_16b.LIVE)
    sequence = [f.service.service_name for f in frames[1:first_live]]
    assert sequence == ["connected", "vid-pid", "device-string", "device-type"]
    link.close()


def test_a_pty_says_how_much_went_and_when_it_drains():
    """A pty's TIOCOUTQ reads 0 whatever waits in it: the link counts what the OS took
    (a non-blocking write) and asks the fd whether it takes bytes again."""
    import os
    import select

    master, slave = os.openpty()
    link = SerialLink(os.ttyname(slave))
    try:
        assert link.open_now() and link.line_event() is LineEvent.OPENED
        assert link.state(False).hides_queue  # its queue is not reported on a pty
        chunk = bytes(216)
        written = [link.write(chunk) for _ in range(400)]  # far more than a pty holds
        assert any(w.sent < len(chunk) for w in written)  # the OS said: no more
        # The kernel moves a pty's bytes on to the reader's side in the background, so room
        # can come back for a while without a read: fill until it stays full.
        while select.select([], [slave], [], 0.2)[1]:
            written.append(link.write(chunk))
        assert link.stats.bytes_written == sum(w.sent for w in written)
        assert not link.state(True).writable
        got = 0
        while select.select([master], [], [], 0.5)[0] and got < link.stats.bytes_written:
            got += len(os.read(master, 65536))
            if link.state(True).writable:
                break
        assert link.state(True).writable and got > 0
    finally:
        link.close()
        os.close(master)
        os.close(slave)


def test_a_pty_drops_what_it_holds_on_request():
    """After a stall the link drops what a pty still holds: the far end then reads only what
    its line discipline already had (about 4 KB), not the kernel's whole buffer."""
    import os
    import select

    master, slave = os.openpty()
    link = SerialLink(os.ttyname(slave))
    try:
        assert link.open_now() and link.line_event() is LineEvent.OPENED
        while select.select([], [slave], [], 0.2)[1]:  # full, and stays full
            link.write(bytes(216))
        assert link.flush() and link.stats.flushes == 1
        got = 0
        while select.select([master], [], [], 0.2)[0]:
            got += len(os.read(master, 65536))
        assert got < link.stats.bytes_written // 2, (got, link.stats.bytes_written)
    finally:
        link.close()
        os.close(master)
        os.close(slave)


def test_a_port_that_reports_its_queue_is_not_flushed():
    link = SerialLink("loop://")
    try:
        assert link.open_now() and link.line_event() is LineEvent.OPENED
        assert link.write(b"H-").sent == 2
        assert not link.flush() and link.stats.flushes == 0
        assert link._adopted.in_waiting == 2  # what was written is still there
    finally:
        link.close()


def test_a_socket_line_keeps_its_send_buffer_small_and_sends_each_tick_at_once():
    """docs/ICD.md, "A stalled line": what a stalled `socket://` can deliver late is bounded
    by the send buffer usb2rc asks for (Linux doubles it); and no tick waits for the far
    end's acknowledgement of the last one (Nagle's algorithm off)."""
    server = socket.create_server(("127.0.0.1", 0))
    link = SerialLink(f"socket://127.0.0.1:{server.getsockname()[1]}")
    try:
        assert link.open_now() and link.line_event() is LineEvent.OPENED
        fd = transport.plain_fd(link._adopted)
        assert fd is not None
        with socket.socket(fileno=os.dup(fd)) as sock:  # the same socket as the link's
            assert sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY)
            assert sock.getsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF) == 2 * SOCKET_SEND_BUFFER
    finally:
        link.close()
        server.close()
