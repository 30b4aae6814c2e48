"""The daemon's outputs start with the objects alive then frozen out of the garbage
collector's full collections (usb2rc/daemon.py, `gc.freeze`: such a collection holds the GIL
for milliseconds, long enough to miss a tick at 500 Hz), and a stopped daemon unfreezes them.
"""

from __future__ import annotations

import gc
from pathlib import Path

from usb2rc.configfile import Config, OutputConfig
from usb2rc.daemon import Daemon
from usb2rc.hid.replay import ReplayBackend

C2 = OutputConfig(protocol="c2-16b", port="loop://", rate_hz=50)


def tracked(thing: object) -> bool:
    """Whether a collection would walk `thing` (it is in a generation, not frozen)."""
    return any(o is thing for o in gc.get_objects())


def test_a_running_daemons_objects_are_out_of_the_collections_until_it_stops(
    tmp_path: Path,
) -> None:
    daemon = Daemon(Config(outputs=(C2,)), ReplayBackend(tmp_path))
    assert tracked(daemon.table)
    try:
        daemon.start()
        assert gc.get_freeze_count() > 0
        assert not tracked(daemon.table) and not tracked(daemon.outputs[0].driver)
    finally:
        daemon.stop()
    assert gc.get_freeze_count() == 0 and tracked(daemon.table)


def test_a_daemon_without_outputs_freezes_nothing(tmp_path: Path) -> None:
    """`monitor` runs a daemon with no output: no tick to keep, nothing frozen."""
    daemon = Daemon(Config(outputs=()), ReplayBackend(tmp_path), outputs=False)
    try:
        daemon.start()
        assert tracked(daemon.table)
    finally:
        daemon.stop()
