"""Live acquisition: the load cell's serial stream, byte for byte, into a contract ``.bin`` capture.

Bytes are appended to the file as they arrive and flushed to disk every ``sync_every_s``, so a
crash or a pulled plug loses at most that much; Ctrl-C (SIGINT) and SIGTERM only set a stop flag,
so the chunk in hand is always written and what is still in the port's buffer is drained before
the file is closed. The capture is raw on purpose (it is the contract's ``.bin``: what the logger
read): frames are decoded alongside only to show progress (frames, rate, dropped).
"""

from __future__ import annotations

import os
import signal
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from workbench.contract.serial import FrameDecoder
from workbench.errors import ContractError, DataError


@dataclass
class AcquireStats:
    """Progress of a recording."""

    bytes: int = 0
    frames: int = 0
    dropped_frames: int = 0
    dropped_bytes: int = 0
    elapsed_s: float = 0.0
    rate_hz: float = 0.0
    stopped_by: str = ""

    def line(self) -> str:
        """The live progress line."""
        return (f"{self.frames:,} frames  {self.rate_hz:7.1f} Hz  dropped {self.dropped_frames} frames / "
                f"{self.dropped_bytes} bytes  {self.bytes / 1e6:.2f} MB  {self.elapsed_s:6.1f} s")


def open_port(port: str, baudrate: int, timeout_s: float = 0.1):
    """Open a serial port or pyserial URL (``/dev/ttyUSB0``, ``loop://``, ``socket://host:port``)."""
    import serial

    try:
        return serial.serial_for_url(port, baudrate=baudrate, timeout=timeout_s)
    except (serial.SerialException, ValueError, OSError) as exc:
        raise DataError(f"cannot open serial port: {exc}", path=port) from exc


class _StopOnSignal:
    """Turn SIGINT/SIGTERM into a stop flag while recording (main thread only)."""

    def __init__(self, event: threading.Event):
        self.event = event
        self.previous = {}
        self.signal_name = ""

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self.previous[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum, frame):
        self.signal_name = signal.Signals(signum).name
        self.event.set()

    def __exit__(self, *exc):
        for sig, handler in self.previous.items():
            signal.signal(sig, handler)
        return False


def record(port, out: str | Path, *, baudrate: int = 921600, duration_s: float | None = None,
           stop: threading.Event | None = None, on_progress: Callable[[AcquireStats], None] | None = None,
           progress_every_s: float = 0.5, sync_every_s: float = 0.5, rate_hz: float | None = None) -> AcquireStats:
    """Record ``port`` (a name/URL, or an open pyserial object) into ``out`` until stopped.

    Stops after ``duration_s``, when ``stop`` is set, or on SIGINT/SIGTERM. Refuses to overwrite an
    existing capture (raw data is never modified). ``rate_hz`` (the load cell's nominal frame rate)
    sets the period for counting dropped frames; by default the median counter step is used.
    """
    out = Path(out)
    if out.exists():
        raise ContractError("capture file exists; raw data is never overwritten", path=out,
                            hint="choose a new file name")
    out.parent.mkdir(parents=True, exist_ok=True)
    ser = open_port(port, baudrate) if isinstance(port, str) else port
    stop = stop or threading.Event()
    decoder = FrameDecoder(period_us=1e6 / rate_hz if rate_hz else None)
    stats = AcquireStats()
    t0 = time.monotonic()
    last_progress = last_sync = t0
    last_frames = 0
    try:
        with open(out, "xb") as fh, _StopOnSignal(stop) as sig:
            def take(chunk: bytes) -> None:
                fh.write(chunk)
                stats.bytes += len(chunk)
                decoder.feed(chunk)

            while True:
                now = time.monotonic()
                if duration_s is not None and now - t0 >= duration_s:
                    stats.stopped_by = "duration"
                    break
                if stop.is_set():
                    stats.stopped_by = sig.signal_name or "stop"
                    break
                chunk = ser.read(max(1, ser.in_waiting))
                if chunk:
                    take(chunk)
                now = time.monotonic()
                if now - last_sync >= sync_every_s:
                    fh.flush()
                    os.fsync(fh.fileno())
                    last_sync = now
                if on_progress and now - last_progress >= progress_every_s:
                    _update(stats, decoder, now - t0, (decoder.frames - last_frames) / (now - last_progress))
                    last_frames, last_progress = decoder.frames, now
                    on_progress(stats)
            # drain what the port already holds: received bytes are never dropped
            while True:
                waiting = ser.in_waiting
                if not waiting:
                    break
                take(ser.read(waiting))
            fh.flush()
            os.fsync(fh.fileno())
    finally:
        if isinstance(port, str):
            ser.close()
    elapsed = time.monotonic() - t0
    _update(stats, decoder, elapsed, decoder.frames / elapsed if elapsed > 0 else 0.0)
    return stats


def _update(stats: AcquireStats, decoder: FrameDecoder, elapsed: float, rate: float) -> None:
    stats.frames = decoder.frames
    stats.dropped_frames = decoder.dropped_frames
    stats.dropped_bytes = decoder.dropped_bytes
    stats.elapsed_s = elapsed
    stats.rate_hz = rate
