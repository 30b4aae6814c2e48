"""atheris: the SUMD stream decoder on coverage-guided inputs.

python tests/fuzz_atheris/fuzz_sumd.py -runs=200000
"""

import sys

import atheris

with atheris.instrument_imports():
    from usb2rc.protocols.sumd import codec as sumd


def test_one_input(data: bytes) -> None:
    if not data:
        return
    step, body = data[0] % 70 + 1, data[1:]
    whole = sumd.SumdDecoder()
    out = whole.feed(body) + whole.flush()
    pieces = sumd.SumdDecoder()
    chunked = []
    for i in range(0, len(body), step):
        chunked += pieces.feed(body[i : i + step])
    chunked += pieces.flush()
    if chunked != out:
        raise AssertionError("chunking changed the result")
    in_frames = 0
    for frame in out:
        raw = sumd.encode_sumd(frame.channels, failsafe=frame.failsafe)
        if raw not in body:
            raise AssertionError(f"invented frame {frame!r}")
        in_frames += len(raw)
    if in_frames + whole.bytes_skipped != len(body):
        raise AssertionError("counters do not add up")


if __name__ == "__main__":
    atheris.Setup(sys.argv, test_one_input)
    atheris.Fuzz()
