"""One package per output protocol, found together: its sans-IO codec (`<name>.codec`), its
line session on the one interface of `usb2rc.lines.session` (`<name>.session`), its output
(`<name>.output`: its registry row, its own config keys and how it is built, registered in
`registry` when imported) and what else is its own (channels, checks). Shared by several:
`stream` (the decoders' resync loop), `crc`, `rc11` (the 11-bit channel block CRSF and SBUS
share, and its scaling) with `rc11_channels` (its `WireScale`, the padding), `channels` (a
channel output's channels, through its protocol's `WireScale`).

Encoders return bytes and raise ValueError on a bad value (a value of the wrong type raises
TypeError where the hot path is compiled: docs/DESIGN.md, "The hot path compiled by
mypyc"); the streaming decoders take bytes in any chunking, return frames, count what they
skip and never raise. No threads, no ports.
"""
