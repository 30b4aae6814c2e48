"""usb2rc: USB HID flight controls to a SERaero C2-16B / HoTT SUMD serial stream."""

__version__ = "0.1.0"
