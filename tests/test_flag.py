"""WakeFlag: the readers' cheap Event: set once, wakes every waiter, never blocks when set."""

from __future__ import annotations

import threading

from usb2rc.runtime.flag import WakeFlag


def test_wait_times_out_while_not_set() -> None:
    flag = WakeFlag()
    assert not flag.is_set()
    assert flag.wait(0.0) is False
    assert flag.wait(-1.0) is False  # a negative pause is "do not block", not an error
    assert flag.wait(0.001) is False


def test_set_wakes_every_waiter_and_stays_set() -> None:
    flag = WakeFlag()
    woken: list[bool] = []
    waiters = [threading.Thread(target=lambda: woken.append(flag.wait(60.0))) for _ in range(3)]
    for thread in waiters:
        thread.start()
    flag.set()
    flag.set()  # a second set() is harmless
    for thread in waiters:
        thread.join(10.0)
    assert woken == [True, True, True]
    assert flag.is_set() and flag.wait(60.0) is True


def test_concurrent_sets_release_once() -> None:
    flag = WakeFlag()
    threads = [threading.Thread(target=flag.set) for _ in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(10.0)
    assert flag.wait(0.0) is True
