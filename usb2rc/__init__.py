"""usb2rc: USB HID flight controls to a SERaero C2-16B / HoTT SUMD serial stream."""

from usb2rc import compiled_path

__version__ = "0.1.0"

# before any module of the hot path is imported: compiled, or from its source
compiled_path.choose()
