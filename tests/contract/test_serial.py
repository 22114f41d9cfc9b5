"""The .bin frame decoder: resynchronisation, counter wraparound, dropped bytes and frames."""

from __future__ import annotations

import numpy as np
import pytest

from workbench.contract.serial import FRAME_SIZE, FrameDecoder, decode_frames, encode_frames


def frames(n=2000, t0=0, period=2000, seed=0):
    rng = np.random.default_rng(seed)
    time_us = t0 + period * np.arange(n)
    counts = rng.integers(-2 ** 31, 2 ** 31 - 1, (n, 6))
    sync = (np.arange(n) % 500 < 50).astype(int)
    return time_us, counts, sync


def test_round_trip():
    t, c, s = frames()
    d = decode_frames(encode_frames(t, c, s))
    np.testing.assert_array_equal(d.time_us, t)
    np.testing.assert_array_equal(d.counts, c)
    np.testing.assert_array_equal(d.sync, s)
    assert d.dropped_bytes == 0 and d.dropped_frames == 0


def test_counter_wraparound_is_unwrapped():
    t, c, s = frames(t0=2 ** 32 - 1_000_000)
    d = decode_frames(encode_frames(t, c, s))
    assert np.all(np.diff(d.time_us) == 2000)
    assert d.time_us[0] == 2 ** 32 - 1_000_000


def test_resync_after_mid_frame_start_corruption_and_loss():
    t, c, s = frames()
    data = bytearray(encode_frames(t, c, s))
    data = data[20:]                                  # starts 20 bytes into frame 0
    base = FRAME_SIZE - 20
    data[base + 32 * 10 + 31] ^= 0xFF                 # frame 11: bad checksum
    del data[base + 32 * 50: base + 32 * 55]          # frames 51-55 lost
    data[base + 32 * 100: base + 32 * 100] = b"\xaa\x55\x00\x01\x02"  # noise with a fake header
    d = decode_frames(bytes(data))
    assert len(d) == 2000 - 1 - 1 - 5
    assert d.dropped_frames == 1 + 5
    assert d.dropped_bytes == len(data) - FRAME_SIZE * len(d)
    assert np.all(np.diff(d.time_us) > 0)
    keep = np.setdiff1d(np.arange(2000), [0, 11, 51, 52, 53, 54, 55])
    np.testing.assert_array_equal(d.counts, c[keep])


def test_header_lookalike_inside_payload_does_not_displace_frames():
    t, c, s = frames(n=300)
    # plant AA 55 plus a payload that makes a "frame" starting inside frame 100 pass its checksum
    c[100, 0] = int.from_bytes(b"\x00\x00\xaa\x55", "little", signed=True)
    data = bytearray(encode_frames(t, c, s))
    d = decode_frames(bytes(data))
    assert len(d) == 300 and d.dropped_bytes == 0


def test_no_valid_frames():
    junk = np.random.default_rng(3).integers(0, 256, 5000, dtype=np.uint8).tobytes().replace(b"\xaa\x55", b"")
    d = decode_frames(junk)
    assert len(d) == 0 and d.dropped_bytes == len(junk)


@pytest.mark.parametrize("chunk", [1, 7, 31, 32, 33, 1000])
def test_incremental_decoder_matches_whole_capture(chunk):
    t, c, s = frames(n=600, t0=2 ** 32 - 300_000)
    data = bytearray(encode_frames(t, c, s))[5:]
    del data[3000:3100]
    whole = decode_frames(bytes(data))
    dec = FrameDecoder()
    got = [dec.feed(bytes(data[i:i + chunk])) for i in range(0, len(data), chunk)]
    times = np.concatenate([g.time_us for g in got])
    np.testing.assert_array_equal(times, whole.time_us)
    assert dec.frames == len(whole)
    assert dec.dropped_bytes + dec.pending_bytes == whole.dropped_bytes
    assert dec.dropped_frames == whole.dropped_frames
