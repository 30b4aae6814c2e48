"""The optional C part: `usb2rc.hid._speedups` (a batch of HID reports drained in one C loop).

Everything else is in pyproject.toml. The extension is optional: where it cannot be built
(no C compiler or no Python headers, as on a bare Pi) the install goes on without it and
usb2rc runs its Python path, which gives the same values (tests/test_speedups.py).
"""

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension("usb2rc.hid._speedups", ["usb2rc/hid/_speedups.c"], optional=True),
    ]
)
