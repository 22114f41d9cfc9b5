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
    out = Path(out)
    if out.exists():
        raise ContractError("capture file exists; raw data is never overwritten", path=out,
                            hint="choose a new file name")
    ser = open_port(port, baudrate) if isinstance(port, str) else port
    # the file is created once the port is open (pyserial clears the port's input on open): its
    # appearance means the recording has started
    fh = _create_capture(out, port, ser)
    port_name = _port_name(port, ser)
    stop = stop or threading.Event()
    capture = _Capture(fh, FrameDecoder(period_us=1e6 / rate_hz if rate_hz else None))
    stats, decoder = capture.stats, capture.decoder
    t0 = time.monotonic()
    fault: tuple[str, BaseException | None] | None = None   # (kind, cause)
    try:
        with fh, _StopOnSignal(stop) as sig:
            try:
                fault = _receive(ser, port, capture, t0, _Progress(on_progress, progress_every_s, t0),
                                 stop=lambda now: _stop_reason(now - t0, duration_s, stop, sig),
                                 stall_s=stall_s, sync_every_s=sync_every_s)
                if fault is None:
                    fault = _drain(ser, capture)
                capture.sync()
            except _StoreFailed as failed:  # writing or syncing the capture failed: disk full, I/O error
                fault = ("disk", failed.cause)
                capture.end_at_last_frame()
    finally:
        _close_port(port, ser)
    elapsed = time.monotonic() - t0
    _update(stats, decoder, elapsed, decoder.frames / elapsed if elapsed > 0 else 0.0)
    if fault is not None:
        stats.stopped_by = fault[0]
        raise _fault(fault[0], fault[1], stats, out, port_name, elapsed, stall_s, capture.lost_bytes)
    return stats


def _create_capture(out: Path, port, ser):
    """Create the capture file, unbuffered (every chunk is one write, the file's size what was stored).

    On failure a port that :func:`record` opened is closed, and the error names the file.
    """
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        return open(out, "xb", buffering=0)
    except OSError as exc:
        if isinstance(port, str):
            ser.close()
        raise DataError(f"cannot create the capture: {exc.strerror or exc}", path=out,
                        hint="check the folder, its permissions and free space") from exc


def _port_name(port, ser) -> str:
    """The port's name for messages: the name given, else the open port's own name."""
    if isinstance(port, str):
        return port
    return getattr(ser, "port", None) or getattr(ser, "portstr", None) or "the serial port"


def _close_port(port, ser) -> None:
    """Close a port that :func:`record` opened (a vanished device may fail to close: ignored)."""
    if isinstance(port, str):
        try:
            ser.close()
        except Exception:  # noqa: BLE001 - a vanished device may fail to close; the capture is what matters
            pass


class _Capture:
    """The open capture file: stores chunks whole, counts and decodes what was stored."""

    def __init__(self, fh, decoder: FrameDecoder):
        self.fh = fh
        self.decoder = decoder
        self.stats = AcquireStats()
        self.lost_bytes = 0   # of the last chunk, what could not be written

    def take(self, chunk: bytes) -> None:
        """Write the whole chunk (a short write continues); count and decode what was stored."""
        view = memoryview(chunk)
        done = 0
        try:
            while done < len(view):
                done += self.fh.write(view[done:])
        except OSError as exc:
            raise _StoreFailed(exc) from exc
        finally:
            if done:
                self.stats.bytes += done
                self.decoder.feed(view[:done])
            self.lost_bytes = len(view) - done

    def sync(self) -> None:
        """Sync the file to disk (a failure is :class:`_StoreFailed`)."""
        try:
            os.fsync(self.fh.fileno())
        except OSError as exc:
            raise _StoreFailed(exc) from exc

    def end_at_last_frame(self) -> None:
        """After a failed write: trim a frame fragment the write cut, then sync (both best effort)."""
        if self.decoder.pending_bytes:
            try:
                os.ftruncate(self.fh.fileno(), self.stats.bytes - self.decoder.pending_bytes)
                self.stats.bytes -= self.decoder.pending_bytes
            except OSError:
                pass
        try:
            os.fsync(self.fh.fileno())
        except OSError:
            pass


class _Progress:
    """Calls ``on_progress`` with fresh stats every ``every_s`` seconds (the rate over that interval)."""

    def __init__(self, on_progress: Callable[[AcquireStats], None] | None, every_s: float, t0: float):
        self.on_progress = on_progress
        self.every_s = every_s
        self.t0 = self.last = t0
        self.last_frames = 0

    def tick(self, capture: _Capture, now: float) -> None:
        """Report if one is due."""
        if not self.on_progress or now - self.last < self.every_s:
            return
        decoder = capture.decoder
        _update(capture.stats, decoder, now - self.t0, (decoder.frames - self.last_frames) / (now - self.last))
        self.last_frames, self.last = decoder.frames, now
        self.on_progress(capture.stats)


def _read_port(ser, size: int | None) -> bytes:
    """Read ``size`` bytes from the port.

    ``size`` None: what the port holds, or when it says 0 or 1 (socket:// always says 1), up to
    4 kB within the port's timeout (0.1 s), so a network port is not read byte by byte.
    """
    if size is None:
        waiting = ser.in_waiting
        size = waiting if waiting > 1 else 4096
    return ser.read(size)


def _stop_reason(elapsed: float, duration_s: float | None, stop: threading.Event, sig: _StopOnSignal) -> str:
    """Why the recording stops now (``"duration"``, the signal's name, ``"stop"``), or ``""``."""
    if duration_s is not None and elapsed >= duration_s:
        return "duration"
    if stop.is_set():
        return sig.signal_name or "stop"
    return ""


def _silence_fault(port) -> tuple[str, None]:
    """The fault of a silent stream: ``vanished`` when its ``/dev`` node is gone, else ``stalled``."""
    gone = isinstance(port, str) and port.startswith("/dev/") and not os.path.exists(port)
    return ("vanished", None) if gone else ("stalled", None)


def _receive(ser, port, capture: _Capture, t0: float, progress: _Progress, *, stop: Callable[[float], str],
             stall_s: float | None, sync_every_s: float) -> tuple[str, BaseException | None] | None:
    """Read the port into the capture until ``stop(now)`` gives a reason (stored as ``stopped_by``).

    Syncs every ``sync_every_s`` and reports progress; returns the fault that ended the reading
    (device vanished, stream stalled for ``stall_s``), or None when it was stopped.
    """
    import serial

    last_sync = last_byte = t0
    while True:
        reason = stop(time.monotonic())
        if reason:
            capture.stats.stopped_by = reason
            return None
        try:
            chunk = _read_port(ser, None)
        except (serial.SerialException, OSError) as exc:
            return ("vanished", exc)
        now = time.monotonic()
        if chunk:
            capture.take(chunk)
            last_byte = now
        elif stall_s and now - last_byte >= stall_s:
            return _silence_fault(port)
        if now - last_sync >= sync_every_s:
            capture.sync()
            last_sync = now
        progress.tick(capture, now)


def _drain(ser, capture: _Capture) -> tuple[str, BaseException] | None:
    """Store what the port already holds (received bytes are never dropped); a vanished device's fault, or None."""
    import serial

    while True:
        try:
            waiting = ser.in_waiting
            chunk = _read_port(ser, waiting) if waiting else b""
        except (serial.SerialException, OSError) as exc:
            return ("vanished", exc)
        if not chunk:
            return None
        capture.take(chunk)


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
