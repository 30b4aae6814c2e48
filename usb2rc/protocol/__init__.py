"""Sans-IO wire codecs: `c2_16b` (SERaero C2-16B), `sumd` (HoTT SUMD), `crsf` (CRSF / ExpressLRS),
`sbus` (Futaba SBUS), the 11-bit channel block CRSF and SBUS share (`rc11`) and the CRCs (`crc`).

Encoders return bytes and raise ValueError on bad input; the streaming decoders take bytes in
any chunking, return frames, count what they skip and never raise. No threads, no ports.
"""

BITS_PER_BYTE_ON_WIRE = 10  # 8N1: start + 8 data + stop (SBUS: its own, `sbus.BITS_PER_BYTE`)
