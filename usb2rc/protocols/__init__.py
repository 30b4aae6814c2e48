"""One package per output protocol: its sans-IO codec (`<name>.codec`), its line session on
the one interface of `usb2rc.lines.session` (`<name>.session`) and what else is its own
(channels, checks), found together; `stream` (the decoders' resync loop), `crc` and `rc11`
(the 11-bit channel block CRSF and SBUS share) serve several.

Encoders return bytes and raise ValueError on bad input; the streaming decoders take bytes in
any chunking, return frames, count what they skip and never raise. No threads, no ports.
"""
