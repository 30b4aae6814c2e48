"""One package per output protocol: its line session (`<name>.session`), on the one interface
of `usb2rc.lines.session`. (The codecs are in `usb2rc.protocol` for now.)"""
