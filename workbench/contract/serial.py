"""The load cell's serial frame (contract section 1, ``.bin`` captures): layout and encoder.

Frames are 32 bytes, little-endian: ``AA 55``, uint32 device time in microseconds
(wrapping at 2**32), six int32 counts (fx, fy, fz, tx, ty, tz), uint8 trigger level,
uint8 checksum (sum of bytes 0-30 modulo 256). SI values are ``calibration @ counts``.

``encode_frames`` writes frames (the virtual lab, tests); ``decode_frames`` reads a whole capture
and ``FrameDecoder`` a live stream, both resynchronising on header and checksum.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FRAME_SIZE = 32
HEADER = b"\xaa\x55"
FRAME_DTYPE = np.dtype(
    [
        ("header", "<u1", (2,)),
        ("time_us", "<u4"),
        ("counts", "<i4", (6,)),
        ("sync", "<u1"),
        ("checksum", "<u1"),
    ]
)
assert FRAME_DTYPE.itemsize == FRAME_SIZE


def encode_frames(time_us: np.ndarray, counts: np.ndarray, sync: np.ndarray) -> bytes:
    """Pack frames; ``time_us`` is taken modulo 2**32 (the device counter wraps)."""
    n = len(time_us)
    frames = np.zeros(n, dtype=FRAME_DTYPE)
    frames["header"] = np.frombuffer(HEADER, dtype=np.uint8)
    frames["time_us"] = (np.asarray(time_us, dtype=np.int64) % (1 << 32)).astype(np.uint32)
    frames["counts"] = np.asarray(counts, dtype=np.int32).reshape(n, 6)
    frames["sync"] = np.asarray(sync, dtype=np.uint8)
    raw = frames.view(np.uint8).reshape(n, FRAME_SIZE)
    frames["checksum"] = (raw[:, :31].astype(np.uint32).sum(axis=1) % 256).astype(np.uint8)
    return frames.tobytes()


def counts_from_si(wrench_si: np.ndarray, calibration: np.ndarray) -> np.ndarray:
    """Invert ``SI = calibration @ counts`` and round to int32 counts (what a device would send)."""
    counts = np.linalg.solve(np.asarray(calibration, float), np.asarray(wrench_si, float).T).T
    return np.rint(counts).astype(np.int32)


# --------------------------------------------------------------------------------------------
# Decoding: find frames by header + checksum, resynchronise after corrupt or dropped bytes,
# unwrap the 32-bit microsecond counter and count the frames the device counter says are missing.

_WRAP = 1 << 32
_HALF_WRAP = 1 << 31


@dataclass(frozen=True)
class DecodedFrames:
    """Frames recovered from a byte buffer, in order.

    ``time_us`` is the device counter unwrapped to int64 (a step of more than half the counter
    range is read as a backward jump, so it shows up as non-monotonic time, not as a 71-minute
    gap). ``offsets`` are the frames' byte positions in the buffer decoded.
    ``dropped_frames`` counts frames missing according to gaps in the device counter,
    ``dropped_bytes`` the bytes that belonged to no valid frame.
    """

    time_us: np.ndarray
    counts: np.ndarray
    sync: np.ndarray
    offsets: np.ndarray
    dropped_bytes: int
    dropped_frames: int

    def __len__(self) -> int:
        return len(self.time_us)


def find_frames(buf: np.ndarray) -> np.ndarray:
    """Byte offsets of the valid, non-overlapping frames in ``buf`` (uint8 array), ascending.

    A candidate starts with the header and carries a matching checksum. Candidates that chain
    with a neighbour 32 bytes away are trusted first; isolated candidates (a lone frame between
    corrupt stretches) are kept where they overlap no trusted frame. A header pattern inside a
    frame's payload that happens to pass the checksum (1 in 256 of header look-alikes) therefore
    cannot displace the true frame stream.
    """
    n = len(buf)
    if n < FRAME_SIZE:
        return np.zeros(0, dtype=np.int64)
    idx = np.flatnonzero((buf[:-1] == HEADER[0]) & (buf[1:] == HEADER[1]))
    idx = idx[idx <= n - FRAME_SIZE].astype(np.int64)
    if len(idx) == 0:
        return idx
    csum = np.concatenate([[0], np.cumsum(buf, dtype=np.int64)])
    ok = ((csum[idx + FRAME_SIZE - 1] - csum[idx]) & 0xFF) == buf[idx + FRAME_SIZE - 1]
    pos = idx[ok]
    if len(pos) == 0:
        return pos
    chained = _member(pos + FRAME_SIZE, pos) | _member(pos - FRAME_SIZE, pos)
    trusted = _greedy(pos[chained])
    loose = pos[~chained]
    if len(loose) and len(trusted):
        j = np.searchsorted(trusted, loose)
        left_ok = (j == 0) | (loose >= trusted[np.maximum(j - 1, 0)] + FRAME_SIZE)
        right_ok = (j == len(trusted)) | (loose + FRAME_SIZE <= trusted[np.minimum(j, len(trusted) - 1)])
        loose = loose[left_ok & right_ok]
    if len(loose):
        trusted = _greedy(np.sort(np.concatenate([trusted, loose])))
    return trusted


def _member(values: np.ndarray, sorted_ref: np.ndarray) -> np.ndarray:
    j = np.searchsorted(sorted_ref, values)
    j = np.minimum(j, len(sorted_ref) - 1)
    return sorted_ref[j] == values


def _greedy(pos: np.ndarray) -> np.ndarray:
    """Drop candidates overlapping an earlier kept one (a Python loop only when overlaps exist)."""
    if len(pos) < 2 or np.all(np.diff(pos) >= FRAME_SIZE):
        return pos
    out, last = [], -FRAME_SIZE
    for p in pos.tolist():
        if p >= last + FRAME_SIZE:
            out.append(p)
            last = p
    return np.asarray(out, dtype=np.int64)


def unwrap_counter(time_u32: np.ndarray, start: int | None = None, previous_u32: int | None = None) -> np.ndarray:
    """Unwrap a 32-bit microsecond counter to int64.

    Steps are taken modulo 2**32; a step of more than 2**31 is read as a backward jump. ``start``
    and ``previous_u32`` continue an earlier unwrapped stretch (the incremental decoder).
    """
    t = np.asarray(time_u32, dtype=np.int64)
    if len(t) == 0:
        return t
    if previous_u32 is None:
        first = t[:1] if start is None else np.asarray([start], dtype=np.int64)
        steps = np.diff(t) % _WRAP
    else:
        first = np.asarray([start], dtype=np.int64)
        steps = np.diff(np.concatenate([[previous_u32], t])) % _WRAP
    steps = np.where(steps >= _HALF_WRAP, steps - _WRAP, steps)
    if previous_u32 is None:
        return np.concatenate([first, first[0] + np.cumsum(steps)])
    return first[0] + np.cumsum(steps)


def count_dropped(time_us: np.ndarray, period_us: float | None = None) -> int:
    """Frames missing from an unwrapped device-time series (gaps of k periods miss k - 1 frames)."""
    if len(time_us) < 2:
        return 0
    d = np.diff(time_us)
    if period_us is None:
        pos = d[d > 0]
        if len(pos) == 0:
            return 0
        period_us = float(np.median(pos))
    missing = np.rint(d[d > 0] / period_us) - 1
    return int(missing[missing > 0].sum())


def _frames_at(buf: np.ndarray, pos: np.ndarray) -> np.ndarray:
    rows = buf[pos[:, None] + np.arange(FRAME_SIZE)]
    return np.ascontiguousarray(rows).view(FRAME_DTYPE).reshape(-1)


def decode_frames(data: bytes | bytearray | memoryview | np.ndarray, period_us: float | None = None) -> DecodedFrames:
    """Decode a whole capture (vectorised): frames, unwrapped device time, dropped bytes and frames.

    ``period_us`` is the nominal frame period used to count missing frames; by default the
    median step of the device counter.
    """
    buf = np.frombuffer(data, dtype=np.uint8) if not isinstance(data, np.ndarray) else data
    pos = find_frames(buf)
    frames = _frames_at(buf, pos) if len(pos) else np.zeros(0, dtype=FRAME_DTYPE)
    time_us = unwrap_counter(frames["time_us"])
    return DecodedFrames(
        time_us=time_us,
        counts=frames["counts"].astype(np.int32).reshape(-1, 6),
        sync=frames["sync"].astype(np.uint8),
        offsets=pos,
        dropped_bytes=int(len(buf) - FRAME_SIZE * len(pos)),
        dropped_frames=count_dropped(time_us, period_us),
    )


class FrameDecoder:
    """Incremental decoder for a live serial stream: feed chunks, get the frames completed so far.

    Bytes that may still begin a frame (the last 31 of a chunk) wait for the next chunk; the
    running totals count every byte and frame the way :func:`decode_frames` would on the whole
    capture, give or take a frame at a chunk boundary.
    """

    #: counter steps seen before the frame period is taken as their median
    LEARN_STEPS = 16

    def __init__(self, period_us: float | None = None):
        self.period_us = period_us
        self._early_steps: list[int] = []
        self.frames = 0
        self.dropped_bytes = 0
        self.dropped_frames = 0
        self._pending = b""
        self._last_u32: int | None = None
        self._last_time: int | None = None

    def feed(self, chunk: bytes) -> DecodedFrames:
        """Decode the frames completed by ``chunk``; update the running totals."""
        data = self._pending + bytes(chunk)
        buf = np.frombuffer(data, dtype=np.uint8)
        pos = find_frames(buf)
        end = int(pos[-1]) + FRAME_SIZE if len(pos) else 0
        # keep what might still start a frame: everything after the last frame, at most 31 bytes
        keep_from = max(end, len(buf) - (FRAME_SIZE - 1))
        self._pending = data[keep_from:]
        self.dropped_bytes += keep_from - FRAME_SIZE * len(pos)
        frames = _frames_at(buf, pos) if len(pos) else np.zeros(0, dtype=FRAME_DTYPE)
        raw = frames["time_us"]
        if self._last_u32 is None:
            time_us = unwrap_counter(raw)
        else:
            time_us = unwrap_counter(raw, start=self._last_time, previous_u32=self._last_u32)
        if len(raw):
            series = time_us if self._last_time is None else np.concatenate([[self._last_time], time_us])
            steps = np.diff(series)
            if self.period_us is None:
                # learn the frame period from the first steps, then count the gaps among them too
                self._early_steps.extend(steps[steps > 0].tolist())
                if len(self._early_steps) >= self.LEARN_STEPS:
                    self.period_us = float(np.median(self._early_steps))
                    early = np.asarray(self._early_steps)
                    self.dropped_frames += count_dropped(np.concatenate([[0], np.cumsum(early)]), self.period_us)
                    self._early_steps = []
            else:
                self.dropped_frames += count_dropped(series, self.period_us)
            self._last_u32 = int(raw[-1])
            self._last_time = int(time_us[-1])
        self.frames += len(pos)
        return DecodedFrames(time_us=time_us, counts=frames["counts"].astype(np.int32).reshape(-1, 6),
                             sync=frames["sync"].astype(np.uint8), offsets=pos, dropped_bytes=0,
                             dropped_frames=0)

    @property
    def pending_bytes(self) -> int:
        """Bytes held back waiting for the rest of a frame."""
        return len(self._pending)
