"""The load cell's serial frame (contract section 1, ``.bin`` captures): layout and encoder.

Frames are 32 bytes, little-endian: ``AA 55``, uint32 device time in microseconds
(wrapping at 2**32), six int32 counts (fx, fy, fz, tx, ty, tz), uint8 trigger level,
uint8 checksum (sum of bytes 0-30 modulo 256). SI values are ``calibration @ counts``.
"""

from __future__ import annotations

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
