"""FlySky iBus: its codec (`codec`), its line session (`session`) and its channels' scale."""

from usb2rc.protocols.channels import WireScale
from usb2rc.protocols.ibus.codec import axis_to_ibus, button_to_ibus

IBUS_SCALE = WireScale(axis_to_ibus, button_to_ibus)  # 1000..2000 µs, centre 1500
