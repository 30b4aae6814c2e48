"""A MAVLink output that does not sign loads no OpenSSL (usb2rc/protocols/mavlink/__init__.py):
pymavlink's hashlib and mavutil's ssl are stand-ins until their first use. One that signs
loads hashlib when it is built, and signs with the real one. Each case in a fresh interpreter
(this one may have loaded them already)."""

from __future__ import annotations

import subprocess
import sys

UNSIGNED = """
import sys
from usb2rc.config.mavlink import MavlinkOptions
from usb2rc.protocols.mavlink.actions import mode_maps
from usb2rc.protocols.mavlink.session import MavlinkEngine
engine = MavlinkEngine(MavlinkOptions())
mode_maps()
import hashlib, ssl
print(sorted(name for name in ("_hashlib", "_ssl") if name in sys.modules))
print(type(hashlib).__name__, type(ssl).__name__)
"""

SIGNED = """
import sys
from usb2rc.protocols.mavlink.codec import MavlinkDecoder
decoder = MavlinkDecoder(bytes(range(32)), 1.7e9)
print("_hashlib" in sys.modules)
import hashlib
from pymavlink.dialects.v20 import common
print(common.hashlib is hashlib, hashlib.sha256(b"abc").hexdigest()[:8])
print(hasattr(hashlib, "no_such_name"))
"""


def run(code: str) -> list[str]:
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    )
    return result.stdout.splitlines()


def test_an_output_that_does_not_sign_loads_no_openssl() -> None:
    loaded, kinds = run(UNSIGNED)
    assert loaded == "[]"
    assert kinds == "LazyModule LazyModule"


def test_an_output_that_signs_loads_hashlib_at_its_build_and_signs_with_it() -> None:
    loaded, same, missing = run(SIGNED)
    assert loaded == "True"
    assert same == "True ba7816bf"  # SHA-256("abc"), FIPS 180-2
    assert missing == "False"
