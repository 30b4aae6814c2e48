"""Fuzzing the stream decoders that eat what comes off a serial line: C2-16B and SUMD.

Each input is built from known frames with garbage between them (random bytes, truncated
and CRC-broken frame look-alikes, runs of header bytes), or is a valid stream mutated at
random; it is fed whole and in random chunks. Checked for every input:

- the decoder never raises, and chunking never changes what it decodes;
- every embedded valid frame comes out, in order. The one allowed exception is a garbage
  look-alike whose CRC happens to be right (1 in 65 536) and that overlaps the real frame:
  the decoder cannot tell them apart, so such an input is counted as "shadowed" and the
  look-alike must itself be a CRC-valid frame present in the input;
- nothing is invented: every decoded frame's bytes occur in the input;
- the counters add up: bytes in = bytes in frames (+ LFs) + bytes skipped.

The fast suite runs a few thousand inputs; `-m slow` runs USB2RC_FUZZ_CODEC_INPUTS (default
1 000 000, split between the two decoders), plus atheris when it is installed.
"""

from __future__ import annotations

import os
import random
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from stress_harness import chunks, env_int, figures, mutate

from usb2rc.protocols.c2_16b import codec as c2_16b
from usb2rc.protocols.sumd import codec as sumd

C2_STATUSES = sorted(c2_16b.DATA_STATUSES)
SERVICE_STATUSES = [0x31 + i for i in range(8)] + list(range(1, 9))


# --- frame pools ----------------------------------------------------------------------------


def _c2_pool(
    rng: random.Random, n: int
) -> list[tuple[c2_16b.DataFrame | c2_16b.ServiceFrame, bytes]]:
    pool = []
    for _ in range(n):
        lf = rng.random() < 0.7
        if rng.random() < 0.75:
            axes = [rng.choice((-32768, 0, 32767, rng.randint(-32768, 32767))) for _ in range(10)]
            raw = c2_16b.encode_data(
                rng.choice(C2_STATUSES),
                rng.randrange(256),
                rng.randrange(256),
                axes,
                rng.getrandbits(32),
                rng.getrandbits(32),
                line_feed=lf,
            )
        else:
            raw = c2_16b.encode_service(
                rng.choice(list(c2_16b.Service)),
                rng.randrange(256),
                rng.randbytes(rng.randint(0, 28)),
                binary_status=rng.random() < 0.3,
                line_feed=lf,
            )
        (frame,) = c2_16b.Decoder().feed(raw)
        pool.append((frame, raw))
    return pool


def _sumd_pool(rng: random.Random, n: int) -> list[tuple[sumd.SumdFrame, bytes]]:
    pool = []
    for _ in range(n):
        count = rng.choice((2, 3, 8, 12, 16, 32, rng.randint(2, 32)))
        raw = sumd.encode_sumd(
            [rng.randrange(0x10000) for _ in range(count)], failsafe=rng.random() < 0.3
        )
        dec = sumd.SumdDecoder()
        (frame,) = dec.feed(raw) + dec.flush()
        pool.append((frame, raw))
    return pool


# --- garbage --------------------------------------------------------------------------------


def _c2_garbage(rng: random.Random, pool: list) -> bytes:
    kind = rng.randrange(8)
    if kind == 0:
        return b""
    if kind == 1:
        return rng.randbytes(rng.randint(1, 80))
    if kind == 2:  # a truncated frame: a plausible candidate that runs into the next frame
        raw = rng.choice(pool)[1]
        return raw[: rng.randint(1, 34)]
    if kind == 3:  # a whole frame with a broken CRC
        raw = bytearray(rng.choice(pool)[1][:35])
        raw[33] ^= 1 << rng.randrange(8)
        return bytes(raw)
    if kind == 4:  # header soup
        return bytes(rng.choice(b"H-\n>!<&%12345678\x00") for _ in range(rng.randint(1, 60)))
    if kind == 5:
        return b"\n" * rng.randint(1, 3)
    if kind == 6:  # a frame with one byte changed somewhere (CRC fails, or status implausible)
        raw = bytearray(rng.choice(pool)[1][:35])
        raw[rng.randrange(2, 35)] ^= rng.randint(1, 255)
        return bytes(raw)
    return b"H" * rng.randint(1, 5) + b"-" * rng.randint(0, 2)


def _sumd_garbage(rng: random.Random, pool: list) -> bytes:
    kind = rng.randrange(7)
    if kind == 0:
        return b""
    if kind == 1:
        return rng.randbytes(rng.randint(1, 80))
    if kind == 2:
        raw = rng.choice(pool)[1]
        return raw[: rng.randint(1, len(raw) - 1)]
    if kind == 3:
        raw = bytearray(rng.choice(pool)[1])
        raw[-1] ^= 1 << rng.randrange(8)
        return bytes(raw)
    if kind == 4:  # plausible long headers that hide what follows until their CRC fails
        return bytes([0xA8, rng.choice((0x01, 0x81)), rng.randint(2, 32)]) * rng.randint(1, 3)
    if kind == 5:
        return bytes(rng.choice(b"\xa8\x01\x81\x02\x20\x00") for _ in range(rng.randint(1, 40)))
    raw = bytearray(rng.choice(pool)[1])
    raw[rng.randrange(1, len(raw))] ^= rng.randint(1, 255)
    return bytes(raw)


# --- checking -------------------------------------------------------------------------------


class Tally:
    def __init__(self) -> None:
        self.inputs = 0
        self.bytes = 0
        self.embedded = 0
        self.recovered = 0
        self.shadowed = 0
        self.accidental = 0
        self.mutated = 0


def _decode_c2(data: bytes, pieces: list[bytes] | None) -> tuple[list, c2_16b.Decoder]:
    dec = c2_16b.Decoder()
    out: list = []
    for piece in pieces if pieces is not None else [data]:
        out.extend(dec.feed(piece))
    out.extend(dec.flush())
    return out, dec


def _decode_sumd(data: bytes, pieces: list[bytes] | None) -> tuple[list, sumd.SumdDecoder]:
    dec = sumd.SumdDecoder()
    out: list = []
    for piece in pieces if pieces is not None else [data]:
        out.extend(dec.feed(piece))
    out.extend(dec.flush())
    return out, dec


def _c2_bytes(frame) -> bytes:
    return c2_16b.encode(frame, line_feed=False)


def _sumd_bytes(frame: sumd.SumdFrame) -> bytes:
    return sumd.encode_sumd(frame.channels, failsafe=frame.failsafe)


def _match(
    data: bytes,
    out: list,
    embedded: list[tuple[object, int, int]],  # (frame, start, length)
    to_bytes,
    tally: Tally,
) -> None:
    """Every embedded frame in `out` in order; the others CRC-valid and present in `data`."""
    i = 0
    accidental_spans: list[tuple[int, int]] = []
    missed: list[tuple[object, int, int]] = []
    for frame in out:
        j = next((k for k in range(i, len(embedded)) if embedded[k][0] == frame), None)
        if j is None:
            raw = to_bytes(frame)
            pos = data.find(raw)
            assert pos >= 0, f"decoded a frame that is not in the input: {frame!r}"
            while pos >= 0:
                accidental_spans.append((pos, pos + len(raw)))
                pos = data.find(raw, pos + 1)
            tally.accidental += 1
            continue
        missed.extend(embedded[i:j])
        i = j + 1
        tally.recovered += 1
    missed.extend(embedded[i:])
    for frame, start, length in missed:
        # the same frame may be embedded twice: then the copy the decoder matched first may
        # be the later one, and the shadowed copy is the other
        copies = [(s, n) for f, s, n in embedded if f == frame] or [(start, length)]
        overlaps = any(a < s + n and s < b for a, b in accidental_spans for s, n in copies)
        assert overlaps, f"embedded frame lost at byte {start}: {frame!r}\ninput {data.hex()}"
        tally.shadowed += 1


def check_c2(data: bytes, embedded: list, rng: random.Random, tally: Tally) -> None:
    out, dec = _decode_c2(data, None)
    chunked, _ = _decode_c2(data, chunks(data, rng))
    assert chunked == out, "chunking changed the result"
    assert dec.bytes_in == len(data)
    accounted = dec.frames * c2_16b.FRAME_LEN + dec.bytes_skipped
    assert accounted <= len(data) <= accounted + dec.frames, (len(data), accounted, dec.frames)
    tally.inputs += 1
    tally.bytes += len(data)
    tally.embedded += len(embedded)
    _match(data, out, embedded, _c2_bytes, tally)


def check_sumd(data: bytes, embedded: list, rng: random.Random, tally: Tally) -> None:
    out, dec = _decode_sumd(data, None)
    chunked, _ = _decode_sumd(data, chunks(data, rng))
    assert chunked == out, "chunking changed the result"
    assert dec.bytes_in == len(data)
    in_frames = sum(sumd.frame_length(len(f.channels)) for f in out)
    assert in_frames + dec.bytes_skipped == len(data)
    tally.inputs += 1
    tally.bytes += len(data)
    tally.embedded += len(embedded)
    _match(data, out, embedded, _sumd_bytes, tally)


def _build(rng: random.Random, pool: list, garbage) -> tuple[bytes, list]:
    parts: list[bytes] = []
    embedded = []
    pos = 0
    for _ in range(rng.randint(0, 4)):
        g = garbage(rng, pool)
        parts.append(g)
        pos += len(g)
        frame, raw = rng.choice(pool)
        embedded.append((frame, pos, len(raw)))
        parts.append(raw)
        pos += len(raw)
    parts.append(garbage(rng, pool))
    return b"".join(parts), embedded


def run_c2(n: int, seed: int, tally: Tally) -> None:
    rng = random.Random(seed)
    pool = _c2_pool(rng, 500)
    for k in range(n):
        if k % 4 == 3:  # a valid stream, mutated: no exception, counters add up, no invention
            stream = b"".join(rng.choice(pool)[1] for _ in range(rng.randint(1, 5)))
            tally.mutated += 1
            check_c2(mutate(stream, rng), [], rng, tally)
        else:
            data, embedded = _build(rng, pool, _c2_garbage)
            check_c2(data, embedded, rng, tally)


def run_sumd(n: int, seed: int, tally: Tally) -> None:
    rng = random.Random(seed)
    pool = _sumd_pool(rng, 500)
    for k in range(n):
        if k % 4 == 3:
            stream = b"".join(rng.choice(pool)[1] for _ in range(rng.randint(1, 5)))
            tally.mutated += 1
            check_sumd(mutate(stream, rng), [], rng, tally)
        else:
            data, embedded = _build(rng, pool, _sumd_garbage)
            check_sumd(data, embedded, rng, tally)


def _figures(tally: Tally, seconds: float) -> dict:
    return {
        "inputs": tally.inputs,
        "mutated_streams": tally.mutated,
        "bytes": tally.bytes,
        "embedded_frames": tally.embedded,
        "recovered": tally.recovered,
        "shadowed_by_crc_collision": tally.shadowed,
        "valid_frames_not_embedded": tally.accidental,
        "seconds": round(seconds, 1),
    }


# --- the fast suite -------------------------------------------------------------------------


def test_c2_seeded_fuzz_fast():
    tally = Tally()
    run_c2(3000, 1, tally)
    assert tally.recovered + tally.shadowed == tally.embedded


def test_sumd_seeded_fuzz_fast():
    tally = Tally()
    run_sumd(3000, 2, tally)
    assert tally.recovered + tally.shadowed == tally.embedded


def test_match_catches_a_lost_frame():
    """The checker itself: a decoder that loses a frame must fail it."""
    rng = random.Random(3)
    frame, raw = _c2_pool(rng, 1)[0]
    with pytest.raises(AssertionError, match="embedded frame lost"):
        _match(raw, [], [(frame, 0, len(raw))], _c2_bytes, Tally())
    with pytest.raises(AssertionError, match="not in the input"):
        _match(b"", [frame], [], _c2_bytes, Tally())


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.lists(st.tuples(st.binary(max_size=60), st.integers(0, 499)), max_size=5),
    st.binary(max_size=60),
    st.randoms(use_true_random=False),
)
def test_c2_hypothesis_frames_in_garbage(parts, tail, rnd):
    pool = _C2_POOL
    data, embedded, pos = b"", [], 0
    for garbage, index in parts:
        frame, raw = pool[index]
        data += garbage
        embedded.append((frame, len(data), len(raw)))
        data += raw
    data += tail
    del pos
    check_c2(data, embedded, random.Random(rnd.random()), Tally())


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.lists(st.tuples(st.binary(max_size=60), st.integers(0, 499)), max_size=5),
    st.binary(max_size=60),
    st.randoms(use_true_random=False),
)
def test_sumd_hypothesis_frames_in_garbage(parts, tail, rnd):
    pool = _SUMD_POOL
    data, embedded = b"", []
    for garbage, index in parts:
        frame, raw = pool[index]
        data += garbage
        embedded.append((frame, len(data), len(raw)))
        data += raw
    data += tail
    check_sumd(data, embedded, random.Random(rnd.random()), Tally())


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=400))
def test_both_decoders_take_any_bytes(data):
    for feed in (_decode_c2, _decode_sumd):
        out, dec = feed(data, None)
        assert dec.bytes_in == len(data)
        assert feed(data, [data[i : i + 1] for i in range(len(data))])[0] == out


_C2_POOL = _c2_pool(random.Random(10), 500)
_SUMD_POOL = _sumd_pool(random.Random(11), 500)


# --- the slow suite -------------------------------------------------------------------------


@pytest.mark.slow
def test_codecs_million_inputs(request):
    total = env_int("USB2RC_FUZZ_CODEC_INPUTS", 1_000_000)
    seed = env_int("USB2RC_FUZZ_SEED", 20240601)
    results = {}
    for name, run, share in (
        ("c2-16b", run_c2, total // 2),
        ("sumd", run_sumd, total - total // 2),
    ):
        tally = Tally()
        t0 = time.monotonic()
        run(share, seed, tally)
        results[name] = _figures(tally, time.monotonic() - t0)
        assert tally.recovered + tally.shadowed == tally.embedded
        # a frame cut one byte short is valid when its last CRC byte equals the next frame's
        # first byte (1 in 256): that is the expected source of shadowing, ~1e-5 per input
        assert tally.shadowed <= max(5, tally.inputs // 2000), "too many shadowed frames"
    figures(request, "fuzz-codecs", {"seed": seed, **results})


ATHERIS_DIR = Path(__file__).parent / "fuzz_atheris"


@pytest.mark.slow
@pytest.mark.parametrize("target", ["fuzz_c2_16b.py", "fuzz_sumd.py"])
def test_codecs_atheris(request, target, tmp_path):
    pytest.importorskip("atheris")
    runs = env_int("USB2RC_ATHERIS_RUNS", 500_000)
    t0 = time.monotonic()
    proc = subprocess.run(
        [sys.executable, str(ATHERIS_DIR / target), f"-runs={runs}", "-seed=1", "-max_len=512"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=1200,
        env=dict(os.environ, PYTHONPATH=str(Path(__file__).parent.parent)),
    )
    output = proc.stdout + proc.stderr
    assert proc.returncode == 0, output[-3000:]
    done = [line for line in output.splitlines() if line.startswith("Done ")]
    figures(
        request,
        f"atheris-{target.removesuffix('.py')}",
        {
            "runs": runs,
            "result": done[-1] if done else "?",
            "seconds": round(time.monotonic() - t0, 1),
        },
    )
