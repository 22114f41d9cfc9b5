"""Live acquisition: the load cell's serial stream, byte for byte, into a contract ``.bin`` capture.

Bytes are written to the file as they arrive (unbuffered) and synced to disk every
``sync_every_s``, so a crash of the machine loses at most that much; Ctrl-C (SIGINT) and SIGTERM
only set a stop flag, so the chunk in hand is always written and what is still in the port's
buffer is drained before the file is closed. The capture is raw on purpose (it is the contract's
``.bin``: what the logger read): frames are decoded alongside only to show progress (frames,
rate, dropped).

The rig's faults end a recording with :class:`AcquisitionFault` (one line, exit status 2 from the
CLI), after the file has been synced and closed:

- the serial device vanishes (cable pulled: the read fails or the device node is gone),
- the stream stalls (no byte for ``stall_s`` seconds),
- the disk is full (or the file size limit is reached) while writing.

In each case every byte received and stored is kept, so every complete frame received before the
fault is in the file; a trailing partial frame the device sent before vanishing or stalling is
kept too (the contract allows partial frames: the reader counts those bytes as dropped), while a
frame fragment that a full disk cut in two (an artefact of the failed write, not of the wire) is
trimmed, so the capture ends at the last complete frame it stored. A fault before any byte was
received leaves no file behind.
"""

from __future__ import annotations

import errno
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


class AcquisitionFault(DataError):
    """A recording ended by a fault of the rig (device gone, stream stalled, disk full).

    The capture was closed validly first; ``stats`` holds what was kept (``stats.stopped_by`` is
    ``"vanished"``, ``"stalled"`` or ``"disk"``), ``path`` the capture (None when nothing was kept).
    """

    def __init__(self, fault: str, stats: AcquireStats, capture: Path | None, hint: str | None = None):
        self.stats = stats
        self.capture = capture
        super().__init__(fault, hint=hint)


class _StoreFailed(Exception):
    """Writing or syncing the capture failed (the OSError is ``cause``)."""

    def __init__(self, cause: OSError):
        super().__init__(str(cause))
        self.cause = cause


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
           progress_every_s: float = 0.5, sync_every_s: float = 0.5, rate_hz: float | None = None,
           stall_s: float | None = 5.0) -> AcquireStats:
    """Record ``port`` (a name/URL, or an open pyserial object) into ``out`` until stopped.

    Stops after ``duration_s``, when ``stop`` is set, or on SIGINT/SIGTERM, and returns the stats.
    Refuses to overwrite an existing capture (raw data is never modified). ``rate_hz`` (the load
    cell's nominal frame rate) sets the period for counting dropped frames; by default the median
    counter step is used. Raises :class:`AcquisitionFault`, after closing the capture validly,
    when the device vanishes, when no byte arrives for ``stall_s`` seconds (None or 0: wait for
    ever) or when the disk is full.
    """
    import serial

    out = Path(out)
    if out.exists():
        raise ContractError("capture file exists; raw data is never overwritten", path=out,
                            hint="choose a new file name")
    ser = open_port(port, baudrate) if isinstance(port, str) else port
    # the file is created once the port is open (pyserial clears the port's input on open): its
    # appearance means the recording has started
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        fh = open(out, "xb", buffering=0)  # unbuffered: every chunk is one write, the file's size what was stored
    except OSError as exc:
        if isinstance(port, str):
            ser.close()
        raise DataError(f"cannot create the capture: {exc.strerror or exc}", path=out,
                        hint="check the folder, its permissions and free space") from exc
    port_name = port if isinstance(port, str) else (getattr(ser, "port", None) or getattr(ser, "portstr", None)
                                                     or "the serial port")
    stop = stop or threading.Event()
    decoder = FrameDecoder(period_us=1e6 / rate_hz if rate_hz else None)
    stats = AcquireStats()
    t0 = time.monotonic()
    last_progress = last_sync = last_byte = t0
    last_frames = 0
    fault: tuple[str, BaseException | None] | None = None   # (kind, cause)
    lost_bytes = 0
    try:
        with fh, _StopOnSignal(stop) as sig:
            def take(chunk: bytes) -> None:
                """Write the whole chunk (a short write continues); count and decode what was stored."""
                nonlocal lost_bytes
                view = memoryview(chunk)
                done = 0
                try:
                    while done < len(view):
                        done += fh.write(view[done:])
                except OSError as exc:
                    raise _StoreFailed(exc) from exc
                finally:
                    if done:
                        stats.bytes += done
                        decoder.feed(view[:done])
                    lost_bytes = len(view) - done

            def sync() -> None:
                try:
                    os.fsync(fh.fileno())
                except OSError as exc:
                    raise _StoreFailed(exc) from exc

            def read_port(size: int | None) -> bytes:
                if size is None:
                    # what the port holds; when it says 0 or 1 (socket:// always says 1), up to 4 kB
                    # within the port's timeout (0.1 s), so a network port is not read byte by byte
                    waiting = ser.in_waiting
                    size = waiting if waiting > 1 else 4096
                return ser.read(size)

            try:
                while True:
                    now = time.monotonic()
                    if duration_s is not None and now - t0 >= duration_s:
                        stats.stopped_by = "duration"
                        break
                    if stop.is_set():
                        stats.stopped_by = sig.signal_name or "stop"
                        break
                    try:
                        chunk = read_port(None)
                    except (serial.SerialException, OSError) as exc:
                        fault = ("vanished", exc)
                        break
                    now = time.monotonic()
                    if chunk:
                        take(chunk)
                        last_byte = now
                    elif stall_s and now - last_byte >= stall_s:
                        gone = isinstance(port, str) and port.startswith("/dev/") and not os.path.exists(port)
                        fault = ("vanished", None) if gone else ("stalled", None)
                        break
                    if now - last_sync >= sync_every_s:
                        sync()
                        last_sync = now
                    if on_progress and now - last_progress >= progress_every_s:
                        _update(stats, decoder, now - t0, (decoder.frames - last_frames) / (now - last_progress))
                        last_frames, last_progress = decoder.frames, now
                        on_progress(stats)
                if fault is None:
                    # drain what the port already holds: received bytes are never dropped
                    while True:
                        try:
                            waiting = ser.in_waiting
                            chunk = read_port(waiting) if waiting else b""
                        except (serial.SerialException, OSError) as exc:
                            fault = ("vanished", exc)
                            break
                        if not chunk:
                            break
                        take(chunk)
                sync()
            except _StoreFailed as failed:  # writing or syncing the capture failed: disk full, I/O error
                fault = ("disk", failed.cause)
                if decoder.pending_bytes:   # a frame fragment cut by the failed write: end at the last frame
                    try:
                        os.ftruncate(fh.fileno(), stats.bytes - decoder.pending_bytes)
                        stats.bytes -= decoder.pending_bytes
                    except OSError:
                        pass
                try:
                    os.fsync(fh.fileno())
                except OSError:
                    pass
    finally:
        if isinstance(port, str):
            try:
                ser.close()
            except Exception:  # noqa: BLE001 - a vanished device may fail to close; the capture is what matters
                pass
    elapsed = time.monotonic() - t0
    _update(stats, decoder, elapsed, decoder.frames / elapsed if elapsed > 0 else 0.0)
    if fault is not None:
        stats.stopped_by = fault[0]
        raise _fault(fault[0], fault[1], stats, out, port_name, elapsed, stall_s, lost_bytes)
    return stats


def _fault(kind: str, cause: BaseException | None, stats: AcquireStats, out: Path, port_name: str,
           elapsed: float, stall_s: float | None, lost_bytes: int) -> AcquisitionFault:
    """The one-line fault, after the capture was closed (an empty capture is removed: nothing to keep)."""
    capture: Path | None = out
    if stats.bytes == 0:
        out.unlink(missing_ok=True)   # written by us just now, empty: leave the name free for the retry
        capture = None
    kept = (f"{stats.frames:,} frames kept in {out}" if capture else f"nothing received, {out} not kept")
    if kind == "vanished":
        text = getattr(cause, "strerror", None) or str(cause or "device node gone")
        why = " (" + " ".join(text.split(" (")[0].split()) + ")"
        return AcquisitionFault(f"serial device {port_name} vanished after {elapsed:.1f} s: {kept}{why}", stats,
                                capture, hint="reconnect it and record the rest into a new file")
    if kind == "stalled":
        return AcquisitionFault(f"serial stream {port_name} stalled (no byte for {stall_s:g} s) after "
                                f"{elapsed:.1f} s: {kept}", stats, capture,
                                hint="check the load cell's power and that it is streaming; --stall-s sets the limit")
    code = getattr(cause, "errno", None)
    what = {errno.ENOSPC: "disk full", errno.EDQUOT: "disk quota exceeded",
            errno.EFBIG: "file size limit reached"}.get(code, f"write failed ({getattr(cause, 'strerror', cause)})")
    kept = f"{stats.frames:,} frames kept" if capture else "nothing kept"
    lost = f"; {lost_bytes:,} received bytes could not be written" if lost_bytes else ""
    hint = ("raise the file size limit (ulimit -f) and record the rest into a new file" if code == errno.EFBIG
            else "free space, or record the rest into a new file on another disk")
    return AcquisitionFault(f"{what} writing {out} after {elapsed:.1f} s: {kept}{lost}", stats, capture, hint=hint)


def _update(stats: AcquireStats, decoder: FrameDecoder, elapsed: float, rate: float) -> None:
    stats.frames = decoder.frames
    stats.dropped_frames = decoder.dropped_frames
    stats.dropped_bytes = decoder.dropped_bytes
    stats.elapsed_s = elapsed
    stats.rate_hz = rate
