"""The parts of a recording, one at a time: storing chunks, stopping, silence, draining, progress."""

from __future__ import annotations

import errno
import threading

import numpy as np
import pytest
import serial

from workbench.contract.serial import FRAME_SIZE, FrameDecoder, encode_frames
from workbench.ingest.acquire import (
    _Capture,
    _drain,
    _Progress,
    _silence_fault,
    _stop_reason,
    _StopOnSignal,
    _StoreFailed,
)


def frames(n, seed=0):
    """``n`` load-cell frames at 500 Hz."""
    rng = np.random.default_rng(seed)
    return encode_frames(1000 + 2000 * np.arange(n), rng.integers(-10_000, 10_000, (n, 6)), np.zeros(n, int))


class LimitedFile:
    """A real file that writes at most ``per_write`` bytes a call, and fails with ENOSPC past ``room``."""

    def __init__(self, path, per_write, room=None):
        self.fh = open(path, "xb", buffering=0)
        self.per_write, self.room, self.stored = per_write, room, 0

    def write(self, data):
        n = min(len(data), self.per_write)
        if self.room is not None:
            if self.stored >= self.room:
                raise OSError(errno.ENOSPC, "No space left on device")
            n = min(n, self.room - self.stored)
        self.stored += self.fh.write(data[:n])
        return n

    def fileno(self):
        return self.fh.fileno()


def test_short_writes_store_the_whole_chunk(tmp_path):
    data = frames(100)
    out = tmp_path / "c.bin"
    cap = _Capture(LimitedFile(out, per_write=7), FrameDecoder())
    cap.take(data[:1000])
    cap.take(data[1000:])
    cap.sync()
    assert out.read_bytes() == data
    assert cap.stats.bytes == len(data) and cap.lost_bytes == 0
    assert cap.decoder.frames == 100


def test_full_disk_counts_what_was_stored_and_ends_at_a_frame(tmp_path):
    data = frames(50)
    room = 10 * FRAME_SIZE + 13        # the disk fills 13 bytes into frame 11
    out = tmp_path / "c.bin"
    cap = _Capture(LimitedFile(out, per_write=64, room=room), FrameDecoder())
    with pytest.raises(_StoreFailed) as failed:
        cap.take(data)
    assert failed.value.cause.errno == errno.ENOSPC
    assert cap.stats.bytes == room and cap.lost_bytes == len(data) - room
    cap.end_at_last_frame()
    assert cap.stats.bytes == 10 * FRAME_SIZE
    assert out.read_bytes() == data[:10 * FRAME_SIZE]


def test_stop_reason():
    stop = threading.Event()
    sig = _StopOnSignal(stop)
    assert _stop_reason(1.0, None, stop, sig) == ""
    assert _stop_reason(1.0, 2.0, stop, sig) == ""
    assert _stop_reason(2.0, 2.0, stop, sig) == "duration"
    stop.set()
    assert _stop_reason(1.0, 2.0, stop, sig) == "stop"
    sig.signal_name = "SIGINT"
    assert _stop_reason(1.0, None, stop, sig) == "SIGINT"
    assert _stop_reason(3.0, 2.0, stop, sig) == "duration"   # the duration is checked first


def test_silence_is_a_vanished_device_only_when_its_node_is_gone(tmp_path):
    assert _silence_fault(str(tmp_path / "no-such-node")) == ("stalled", None)   # not under /dev/
    assert _silence_fault("/dev/ttyWB-no-such-device") == ("vanished", None)
    assert _silence_fault("/dev/null") == ("stalled", None)
    assert _silence_fault("loop://") == ("stalled", None)
    assert _silence_fault(object()) == ("stalled", None)   # an open port object


def test_drain_stores_what_the_port_holds(tmp_path):
    data = frames(120)                 # 3840 bytes: within loop://'s 4096-byte buffer
    ser = serial.serial_for_url("loop://", timeout=0.1)
    ser.write(data)
    out = tmp_path / "c.bin"
    with open(out, "xb", buffering=0) as fh:
        cap = _Capture(fh, FrameDecoder())
        assert _drain(ser, cap) is None
    assert out.read_bytes() == data and cap.decoder.frames == 120
    ser.close()


def test_drain_reports_a_vanished_port(tmp_path):
    class Gone:
        @property
        def in_waiting(self):
            raise serial.SerialException("device reports readiness to read but returned no data")

    with open(tmp_path / "c.bin", "xb", buffering=0) as fh:
        kind, cause = _drain(Gone(), _Capture(fh, FrameDecoder()))
    assert kind == "vanished" and "readiness" in str(cause)


def test_progress_reports_when_due_with_the_interval_rate(tmp_path):
    seen = []
    data = frames(150)
    with open(tmp_path / "c.bin", "xb", buffering=0) as fh:
        cap = _Capture(fh, FrameDecoder(period_us=2000))
        progress = _Progress(lambda s: seen.append((s.frames, s.rate_hz, s.elapsed_s)), every_s=0.5, t0=10.0)
        cap.take(data[:100 * FRAME_SIZE])
        progress.tick(cap, 10.4)           # not due yet
        assert seen == []
        progress.tick(cap, 10.5)
        cap.take(data[100 * FRAME_SIZE:])
        progress.tick(cap, 11.0)           # due again only 0.5 s after the last report
        progress.tick(cap, 11.5)
    assert seen[0] == (100, pytest.approx(200.0), pytest.approx(0.5))
    assert seen[1] == (150, pytest.approx(100.0), pytest.approx(1.0))
    assert len(seen) == 3 and seen[2] == (150, pytest.approx(0.0), pytest.approx(1.5))
    _Progress(None, 0.5, 0.0).tick(cap, 100.0)   # no callback: nothing to call
