"""The optional C parts: `usb2rc.hid._speedups` (a batch of HID reports drained in one C loop)
and `usb2rc.nodes._steady` (a steady node's step).

Everything else is in pyproject.toml. The extension is optional: where it cannot be built
(no C compiler or no Python headers, as on a bare Pi) the install goes on without it and
usb2rc runs its Python path, which gives the same values (tests/test_speedups.py).
"""

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension("usb2rc.hid._speedups", ["usb2rc/hid/_speedups.c"], optional=True),
        Extension("usb2rc.nodes._steady", ["usb2rc/nodes/_steady.c"], optional=True),
    ]
)
