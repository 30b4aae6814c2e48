"""argparse `type=` checks shared by the subcommands: a wrong argument is a usage error
(exit 2, argparse's message naming the option) before anything starts."""

from __future__ import annotations

import argparse
import os


def replay_dir(value: str) -> str:
    """--replay DIR: a directory that exists (an empty one is fine: devices may come later)."""
    if not os.path.isdir(value):
        reason = "not a directory" if os.path.exists(value) else "no such directory"
        raise argparse.ArgumentTypeError(f"{value}: {reason} (a folder of hid-recorder files)")
    return value
