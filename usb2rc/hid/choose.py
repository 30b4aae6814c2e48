"""The backend factory: the one module that knows every HID backend."""

from __future__ import annotations

from usb2rc.hid.backend import Backend


def choose_backend(replay: str | None, loop: bool = False) -> Backend:
    """The replay backend on a folder of hid-recorder files, else hidapi (real devices).
    Imported on use: a replay run never loads the hidapi C library."""
    if replay:
        from usb2rc.hid.replay import ReplayBackend

        return ReplayBackend(replay, loop=loop)
    from usb2rc.hid.hidapi_backend import HidapiBackend

    return HidapiBackend()
