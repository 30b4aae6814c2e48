"""argparse `type=` checks shared by the subcommands: a wrong argument is a usage error
(exit 2, argparse's message naming the option) before anything starts."""

from __future__ import annotations

import argparse
import os
import sys

from usb2rc.examples import resolve_replay


def replay_dir(value: str) -> str:
    """--replay DIR: a directory that exists (an empty one is fine: devices may come later).

    `demo` is the built-in recordings (usb2rc.examples.resolve_replay says when a ./demo
    folder takes its place)."""
    path, note = resolve_replay(value)
    if note is not None:
        print(f"usb2rc: {note}", file=sys.stderr)
    if not os.path.isdir(path):
        reason = "not a directory" if os.path.exists(path) else "no such directory"
        raise argparse.ArgumentTypeError(
            f"{value}: {reason} (a folder of hid-recorder files, or `demo` for the built-in ones)"
        )
    return path
