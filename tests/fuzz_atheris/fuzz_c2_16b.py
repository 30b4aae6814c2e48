"""atheris: the C2-16B stream decoder on coverage-guided inputs.

    python tests/fuzz_atheris/fuzz_c2_16b.py -runs=200000

The first input byte picks a chunk size; the rest is fed in those chunks and whole, and the
results must agree; every decoded frame must re-encode to bytes present in the input.
"""

import sys

import atheris

with atheris.instrument_imports():
    from usb2rc.protocols.c2_16b import codec as c2_16b


def test_one_input(data: bytes) -> None:
    if not data:
        return
    step, body = data[0] % 40 + 1, data[1:]
    whole = c2_16b.Decoder()
    out = whole.feed(body) + whole.flush()
    pieces = c2_16b.Decoder()
    chunked = []
    for i in range(0, len(body), step):
        chunked += pieces.feed(body[i : i + step])
    chunked += pieces.flush()
    if chunked != out:
        raise AssertionError("chunking changed the result")
    for frame in out:
        if c2_16b.encode(frame, line_feed=False) not in body:
            raise AssertionError(f"invented frame {frame!r}")
    accounted = whole.frames * c2_16b.FRAME_LEN + whole.bytes_skipped
    if not accounted <= len(body) <= accounted + whole.frames:
        raise AssertionError("counters do not add up")


if __name__ == "__main__":
    atheris.Setup(sys.argv, test_one_input)
    atheris.Fuzz()
