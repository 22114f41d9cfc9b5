"""Live acquisition through real pyserial code paths: loop:// and a pty pair fed with frames."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
import tty

import numpy as np
import pytest
import serial

from workbench.cli import main
from workbench.contract.serial import decode_frames, encode_frames
from workbench.errors import ContractError
from workbench.ingest.acquire import record


def capture(n=3000, t0=2 ** 32 - 2_000_000, seed=0):
    """Frames as a 500 Hz load cell sends them (the counter wraps after 1000 frames)."""
    rng = np.random.default_rng(seed)
    t = t0 + 2000 * np.arange(n)
    return encode_frames(t, rng.integers(-10_000, 10_000, (n, 6)), (np.arange(n) % 500 < 50).astype(int))


def test_loop_url_records_every_byte_with_progress(tmp_path):
    data = capture()
    ser = serial.serial_for_url("loop://", timeout=0.05)
    seen = []

    def feed():
        for i in range(0, len(data), 4096):
            ser.write(data[i:i + 4096])
            time.sleep(0.01)

    writer = threading.Thread(target=feed)
    writer.start()
    out = tmp_path / "r1.loadcell.bin"
    stats = record(ser, out, duration_s=1.5, on_progress=seen.append, progress_every_s=0.1)
    writer.join()
    assert out.read_bytes() == data
    assert stats.frames == 3000 and stats.dropped_frames == 0 and stats.dropped_bytes == 0
    assert stats.stopped_by == "duration"
    assert len(seen) >= 3 and seen[-1].frames > 0
    assert len(decode_frames(out.read_bytes())) == 3000


def test_progress_counts_dropped_frames(tmp_path):
    data = bytearray(capture(n=1000))
    del data[32 * 400: 32 * 410]        # ten frames lost on the wire
    data[32 * 700 + 3] ^= 0xFF          # one corrupt frame
    ser = serial.serial_for_url("loop://", timeout=0.05)
    writer = threading.Thread(target=ser.write, args=(bytes(data),))  # loop:// holds 4 kB; feed as it drains
    writer.start()
    stats = record(ser, tmp_path / "c.bin", duration_s=1.0)
    writer.join()
    assert stats.frames == 989 and stats.dropped_frames == 11 and stats.dropped_bytes == 32


def test_stop_event_and_no_overwrite(tmp_path):
    ser = serial.serial_for_url("loop://", timeout=0.05)
    stop = threading.Event()
    threading.Timer(0.3, stop.set).start()
    out = tmp_path / "c.bin"
    assert record(ser, out, stop=stop).stopped_by == "stop"
    with pytest.raises(ContractError, match="never overwritten"):
        record(ser, out, duration_s=0.1)


@pytest.fixture
def pty_pair():
    master, slave = os.openpty()
    tty.setraw(slave)  # no line discipline: bytes pass as they are (what pyserial sets anyway)
    yield master, os.ttyname(slave)
    os.close(master)
    os.close(slave)


def _fd_target(fd: str) -> str | None:
    try:
        return os.readlink(f"/proc/self/fd/{fd}")
    except OSError:
        return None


def test_cli_records_a_pty_for_a_duration(tmp_path, pty_pair, capsys):
    master, port = pty_pair
    data = capture(n=1500)

    def feed():
        # write once the recorder has opened the port (pyserial's open empties its input buffer): a second
        # descriptor of this process on the slave; a fixed sleep lost the first frames on a loaded machine
        deadline = time.monotonic() + 30
        while sum(_fd_target(fd) == port for fd in os.listdir("/proc/self/fd")) < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.05)
        for i in range(0, len(data), 2048):
            os.write(master, data[i:i + 2048])
            time.sleep(0.005)

    threading.Thread(target=feed, daemon=True).start()
    out = tmp_path / "r1.loadcell.bin"
    assert main(["acquire", "--port", port, "--out", str(out), "--duration", "1.5", "--rate-hz", "500"]) == 0
    assert out.read_bytes() == data
    assert "1,500 frames" in capsys.readouterr().err


@pytest.mark.slow
def test_ctrl_c_loses_nothing_already_received(tmp_path, pty_pair):
    master, port = pty_pair
    out = tmp_path / "r1.loadcell.bin"
    proc = subprocess.Popen([sys.executable, "-m", "workbench.cli", "acquire", "--port", port, "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 20
    while not out.exists() and time.time() < deadline:
        time.sleep(0.05)
    data = capture(n=4000)
    for i in range(0, len(data), 1024):
        os.write(master, data[i:i + 1024])
    time.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    assert "stopped (SIGINT)" in err
    assert out.read_bytes() == data
