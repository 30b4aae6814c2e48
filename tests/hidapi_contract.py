"""What cython-hidapi's `hidraw` module does, as a contract a fake must keep too.

The same checks run against the real library (hidapi 0.15.0, cython-hidapi 0.15.0) on a
umockdev device in a subprocess under the preload library (`run_stdio()`, driven by
`umockdev_harness.run_real_contract`) and against the fake `hid` module of the unit tests
(tests/test_hidapi_backend.py), so the fake cannot drift from the library it stands for.

Measured on the real library (umockdev 0.17.16; the node is a pty the testbed writes):

- `enumerate(0, 0)`: one dict per top-level collection with `path` (bytes), `vendor_id`,
  `product_id`, `release_number`, `interface_number`, `usage_page`, `usage`, `bus_type`
  (ints) and `serial_number`, `manufacturer_string`, `product_string` (str; "" when the
  device has none). The usage comes from sysfs `report_descriptor`, reached through the
  hidraw node's `device` link. Strings are the USB device's sysfs attributes.
- `device().open_path(path)`: `path` must be bytes (a str raises TypeError); a missing node
  or a node it may not open raises exactly `OSError("open failed")`, errno None: the cause
  (ENOENT, EACCES) is only in `device().error()`, e.g. "Failed to open a device with path
  '/dev/nothing': No such file or directory".
- Handles are **blocking** after open. `read(n)` and `read(n, 0)` are the same call,
  `hid_read()`: it waits for a report, however long. A timeout > 0 is `hid_read_timeout()`:
  `[]` after about that many ms without a report, the report at once when one comes.
- `set_nonblocking(1)` returns 0; then `read(n)` and `read(n, 0)` return `[]` at once when
  nothing is queued. `read(n, ms)` with ms > 0 still waits up to ms (the flag does not
  matter there). `set_nonblocking(0)` makes `read(n)` wait again.
- A report comes back as a list of ints, the bytes as the device sent them (report ID first
  when the device uses IDs).
- Unplug: a reader waiting in `read` (with or without a timeout) wakes at once and raises
  `OSError("read error")`; every read after that raises the same, blocking or not, even if
  a report was still queued. The path is gone from `enumerate()`, and `open_path` on it
  raises `OSError("open failed")`. Nothing ever returns `[]` for an unplug.
- `get_report_descriptor()` returns a list of ints (from the HIDIOCGRDESC ioctl).
- `get_input_report(id, n)` on a device that does not answer (here: the ioctl is not mocked,
  ENOTTY; a real stick without GET_REPORT gives EPIPE) raises `OSError("read error")`.
- After `close()` (twice is fine) `read`, `set_nonblocking`, `get_report_descriptor` and
  `write` raise `ValueError("not open")`.
- `write(data)` (bytes or a list of ints; the report ID first, 0 for a device without IDs)
  returns the number of bytes written, all of `data`, and the device gets exactly `data`. A
  failed write does not raise: it returns -1, and `error()` says why as a str (after an
  unplug: WRITE_GONE_ERROR). A second handle on the same path writes while the first reads.

umockdev artifacts, not library behaviour (the checks avoid them; see umockdev_bed.py):
reports queued on the pty come back glued in one read, and a read shorter than the report
leaves the rest for the next read (hidraw returns one report per read and drops the rest);
`get_manufacturer_string()` and friends fail on the opened handle (hidapi looks the device up
by the fstat() device number, which the testbed does not map back to sysfs).
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

# The T.16000M's descriptor (tests/data/real-devices.json): 64-byte reports, no report ID.
DESCRIPTOR = bytes.fromhex(
    "05010904a101050919012910150025013500450175019510810205010939150025073500463b0165147504"
    "9501814281010930150026ff3f350046ff3f6500750e950181027502950181010931750e95018102750295"
    "0181010935093615002"
    "6ff00350046ff0065007508950281027508953781010600ff27ffff0000090175089504b1a2c0"
)
VID, PID = 0x044F, 0xB10A
MISSING_PATH = b"/dev/hidraw-missing"
OUTPUT = bytes([0x00, 0x05, 0x00, 0x08])  # an output report without ID: 0 first
WRITE_GONE_ERROR = "Input/output error"
READ_SIZE = 1024

BLOCKED_S = 0.3  # a read still waiting after this long is taken as blocking
PROMPT_S = 0.05  # "at once"
WOKEN_S = 2.0  # a blocked read must end within this after its report / the unplug
TIMEOUT_MS = 200
ENTRY_KEYS = {
    "path": bytes,
    "vendor_id": int,
    "product_id": int,
    "serial_number": str,
    "release_number": int,
    "manufacturer_string": str,
    "product_string": str,
    "usage_page": int,
    "usage": int,
    "interface_number": int,
    "bus_type": int,
}


class Rig(Protocol):
    """A `hid`-like module and a way to plug a device, send its reports and unplug it."""

    hid: Any

    def plug(self) -> bytes:
        """A new device with DESCRIPTOR, no serial; its path."""
        ...

    def report(self, path: bytes, data: bytes) -> None:
        """The device sends `data`; it is there to read when this returns."""
        ...

    def unplug(self, path: bytes) -> None:
        """The device is gone (node removed, readers woken) when this returns."""
        ...

    def written(self, path: bytes) -> bytes:
        """What the device received (writes to it) since the last call."""
        ...


class ContractError(AssertionError):
    pass


def expect(condition: bool, message: str) -> None:
    if not condition:
        raise ContractError(message)


def report_bytes(n: int) -> bytes:
    """A distinct 64-byte report (no byte a tty would take as a control character)."""
    return bytes([n & 0xFF, 0x00, 0x08]) + bytes(61)


class Call:
    """`fn()` on its own thread; `wait(timeout)` is a deadline, never a bare sleep."""

    def __init__(self, fn: Callable[[], Any]) -> None:
        self.result: Any = None
        self.error: BaseException | None = None
        self.ended_at: float | None = None
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(fn,), daemon=True)
        # daemon: a read the library never returns from must not keep the process alive;
        # the check that started it has already failed by then
        self._thread.start()

    def _run(self, fn: Callable[[], Any]) -> None:
        try:
            self.result = fn()
        except BaseException as exc:
            self.error = exc
        finally:
            self.ended_at = time.monotonic()
            self._done.set()

    def wait(self, timeout: float) -> bool:
        return self._done.wait(timeout)


def raises(fn: Callable[[], Any], kind: type[BaseException], message: str) -> BaseException:
    """fn() raises exactly `kind` (not a subclass) with str() == message."""
    try:
        fn()
    except BaseException as exc:
        expect(
            type(exc) is kind and str(exc) == message,
            f"expected {kind.__name__}({message!r}), got {type(exc).__name__}({exc!s})",
        )
        return exc
    raise ContractError(f"expected {kind.__name__}({message!r}), nothing was raised")


def timed(fn: Callable[[], Any]) -> tuple[Any, float]:
    start = time.monotonic()
    result = fn()
    return result, time.monotonic() - start


def opened(rig: Rig, path: bytes) -> Any:
    handle = rig.hid.device()
    handle.open_path(path)
    return handle


def blocked_then(call: Call, what: str) -> None:
    expect(not call.wait(BLOCKED_S), f"{what} returned at once ({call.result!r}): not blocking")


# --- the checks -----------------------------------------------------------------------------


def check_enumerate_entry(rig: Rig) -> None:
    path = rig.plug()
    entries = [e for e in rig.hid.enumerate(0, 0) if e.get("path") == path]
    expect(len(entries) == 1, f"enumerate() lists {path!r} {len(entries)} times")
    entry = entries[0]
    for key, kind in ENTRY_KEYS.items():
        expect(key in entry, f"enumerate() entry has no {key!r}")
        expect(type(entry[key]) is kind, f"{key}: {type(entry[key]).__name__}, not {kind}")
    got = (entry["vendor_id"], entry["product_id"], entry["usage_page"], entry["usage"])
    expect(got == (VID, PID, 1, 4), f"vid, pid, usage page, usage: {got}")
    expect(entry["serial_number"] == "", f"no serial: {entry['serial_number']!r}")
    rig.unplug(path)


def check_open_missing_path(rig: Rig) -> None:
    handle = rig.hid.device()
    exc = raises(lambda: handle.open_path(MISSING_PATH), OSError, "open failed")
    assert isinstance(exc, OSError)  # `raises` checked its type
    expect(exc.errno is None, f"errno {exc.errno}: the library gives none")
    raises(lambda: handle.open_path(MISSING_PATH.decode()), TypeError, _str_path_message())


def _str_path_message() -> str:
    return "Argument 'path' has incorrect type (expected bytes, got str)"


def check_descriptor_and_input_report(rig: Rig) -> None:
    path = rig.plug()
    handle = opened(rig, path)
    descriptor = handle.get_report_descriptor()
    expect(type(descriptor) is list, f"descriptor is a {type(descriptor).__name__}")
    expect(bytes(descriptor) == DESCRIPTOR, "descriptor differs from the device's")
    raises(lambda: handle.get_input_report(0, 65), OSError, "read error")
    handle.close()
    rig.unplug(path)


def check_blocking_by_default(rig: Rig) -> None:
    path = rig.plug()
    handle = opened(rig, path)
    for n, read in enumerate((lambda: handle.read(64), lambda: handle.read(64, 0)), 1):
        call = Call(read)
        blocked_then(call, "read() on a new handle")
        rig.report(path, report_bytes(n))
        expect(call.wait(WOKEN_S), "a blocked read() did not return the report")
        expect(call.error is None, f"read() raised {call.error!r}")
        expect(call.result == list(report_bytes(n)), f"read() returned {call.result!r}")
    handle.close()
    rig.unplug(path)


def check_nonblocking_polls(rig: Rig) -> None:
    path = rig.plug()
    handle = opened(rig, path)
    expect(handle.set_nonblocking(1) == 0, "set_nonblocking(1) did not return 0")
    for read in (lambda: handle.read(64), lambda: handle.read(64, 0)):
        data, took = timed(read)
        expect(data == [] and took < PROMPT_S, f"non-blocking poll: {data!r} after {took:.3f} s")
    rig.report(path, report_bytes(3))
    data, took = timed(lambda: handle.read(64))
    expect(data == list(report_bytes(3)) and took < PROMPT_S, f"queued report: {data!r}")
    expect(handle.set_nonblocking(0) == 0, "set_nonblocking(0) did not return 0")
    call = Call(lambda: handle.read(64))
    blocked_then(call, "read() after set_nonblocking(0)")
    rig.report(path, report_bytes(4))
    expect(call.wait(WOKEN_S) and call.result == list(report_bytes(4)), "blocking again")
    handle.close()
    rig.unplug(path)


def check_timeouts(rig: Rig) -> None:
    path = rig.plug()
    handle = opened(rig, path)
    for nonblocking in (0, 1):
        handle.set_nonblocking(nonblocking)
        data, took = timed(lambda: handle.read(64, TIMEOUT_MS))
        low, high = TIMEOUT_MS / 1000 * 0.9, TIMEOUT_MS / 1000 + 0.5
        expect(data == [], f"read(64, {TIMEOUT_MS}) with nothing sent returned {data!r}")
        expect(low <= took <= high, f"read(64, {TIMEOUT_MS}) took {took:.3f} s")
        rig.report(path, report_bytes(5 + nonblocking))
        data, took = timed(lambda: handle.read(64, 1000))
        expect(data == list(report_bytes(5 + nonblocking)), f"read(64, 1000): {data!r}")
        expect(took < PROMPT_S, f"a queued report took {took:.3f} s")
    handle.close()
    rig.unplug(path)


def check_unplug_wakes_readers(rig: Rig) -> None:
    for read_args in ((64,), (64, 5000)):
        path = rig.plug()
        handle = opened(rig, path)
        call = Call(functools.partial(handle.read, *read_args))
        blocked_then(call, f"read{read_args}")
        rig.unplug(path)
        expect(call.wait(WOKEN_S), f"read{read_args} did not wake at the unplug")
        expect(call.result is None, f"read{read_args} at unplug returned {call.result!r}")
        expect(
            type(call.error) is OSError and str(call.error) == "read error",
            f"read{read_args} at unplug raised {call.error!r}",
        )
        handle.close()


def check_after_unplug(rig: Rig) -> None:
    path = rig.plug()
    handle = opened(rig, path)
    rig.report(path, report_bytes(7))  # still queued at the unplug: lost, not returned
    rig.unplug(path)
    _, took = timed(lambda: raises(lambda: handle.read(64, 1000), OSError, "read error"))
    expect(took < PROMPT_S, f"read after unplug took {took:.3f} s to fail")
    handle.set_nonblocking(1)
    raises(lambda: handle.read(64), OSError, "read error")
    handle.close()
    expect(all(e["path"] != path for e in rig.hid.enumerate(0, 0)), "enumerate() still lists it")
    raises(lambda: rig.hid.device().open_path(path), OSError, "open failed")


def check_closed_handle(rig: Rig) -> None:
    path = rig.plug()
    handle = opened(rig, path)
    handle.close()
    handle.close()
    raises(lambda: handle.read(64), ValueError, "not open")
    raises(lambda: handle.read(64, 100), ValueError, "not open")
    raises(lambda: handle.set_nonblocking(1), ValueError, "not open")
    raises(lambda: handle.get_report_descriptor(), ValueError, "not open")
    rig.unplug(path)


def check_write(rig: Rig) -> None:
    path = rig.plug()
    reader, writer = opened(rig, path), opened(rig, path)
    pending = Call(lambda: reader.read(64, 2000))
    for data in (OUTPUT, list(OUTPUT)):
        result = writer.write(data)
        expect(result == len(OUTPUT), f"write({data!r}) returned {result!r}")
        got = rig.written(path)
        expect(got == OUTPUT, f"the device got {got.hex()} for write({data!r})")
    rig.report(path, report_bytes(8))  # the first handle's read goes on meanwhile
    expect(pending.wait(WOKEN_S) and pending.result == list(report_bytes(8)), "read beside")
    rig.unplug(path)
    result = writer.write(OUTPUT)
    expect(result == -1, f"write after unplug returned {result!r}")
    error = writer.error()
    expect(error == WRITE_GONE_ERROR, f"error() after a failed write: {error!r}")
    writer.close()
    raises(lambda: writer.write(OUTPUT), ValueError, "not open")
    reader.close()


CHECKS: dict[str, Callable[[Rig], None]] = {
    "enumerate_entry": check_enumerate_entry,
    "open_missing_path": check_open_missing_path,
    "descriptor_and_input_report": check_descriptor_and_input_report,
    "blocking_by_default": check_blocking_by_default,
    "nonblocking_polls": check_nonblocking_polls,
    "timeouts": check_timeouts,
    "unplug_wakes_readers": check_unplug_wakes_readers,
    "after_unplug": check_after_unplug,
    "closed_handle": check_closed_handle,
    "write": check_write,
}


@dataclass(frozen=True)
class Result:
    check: str
    ok: bool
    detail: str = ""


def run_contract(rig: Rig) -> list[Result]:
    results = []
    for name, check in CHECKS.items():
        try:
            check(rig)
        except Exception as exc:
            results.append(Result(name, False, f"{type(exc).__name__}: {exc}"))
        else:
            results.append(Result(name, True))
    return results


def failures(results: list[Result]) -> list[str]:
    return [f"{r.check}: {r.detail}" for r in results if not r.ok]


# --- the real library, in a process under the umockdev preload ---------------------------------


class StdioRig:
    """Asks the parent (which drives the testbed) to plug, send and unplug: one JSON line
    out per request on stdout, one JSON line back on stdin when it is done."""

    def __init__(self, hid: Any) -> None:
        self.hid = hid

    def _ask(self, **request: Any) -> dict[str, Any]:
        print(json.dumps({"request": request}), flush=True)
        reply = json.loads(sys.stdin.readline())
        if "error" in reply:
            raise RuntimeError(f"testbed: {reply['error']}")
        return dict(reply)

    def plug(self) -> bytes:
        return str(self._ask(op="plug")["path"]).encode()

    def report(self, path: bytes, data: bytes) -> None:
        self._ask(op="report", path=path.decode(), data=data.hex())

    def unplug(self, path: bytes) -> None:
        self._ask(op="unplug", path=path.decode())

    def written(self, path: bytes) -> bytes:
        return bytes.fromhex(self._ask(op="written", path=path.decode())["data"])


def run_stdio() -> None:
    import hidraw  # the real library; only importable where cython-hidapi is installed

    results = run_contract(StdioRig(hidraw))
    print(json.dumps({"results": [r.__dict__ for r in results]}), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stdio", action="store_true", help="run against hidraw; see StdioRig")
    args = parser.parse_args()
    if not args.stdio:
        parser.error("only --stdio (run by umockdev_harness.run_real_contract)")
    run_stdio()


if __name__ == "__main__":
    main()
