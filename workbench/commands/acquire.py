"""``workbench acquire --port PORT --out FILE.bin``: record the load cell's serial stream."""

from __future__ import annotations

import sys
from pathlib import Path

from workbench.commands._help import add_verb


def register(sub) -> None:
    """Add the ``acquire`` verb."""
    p = add_verb(
        sub, "acquire", help="record the load cell's serial stream into a .bin capture (live progress)",
        description="Read the load cell's serial port and append every byte to a .bin capture (data contract "
        "section 1) while showing frames, frame rate and dropped frames/bytes. Stops on Ctrl-C or after "
        "--duration; nothing already received is lost (the port's buffer is drained and the file synced). "
        "PORT is a device path or any pyserial URL (loop://, socket://host:port, rfc2217://...). An existing "
        "capture is never overwritten. The rig's faults end the recording with one line and exit status 2, "
        "the capture closed and kept: the device vanishing (cable pulled), the stream stalling (no byte for "
        "--stall-s seconds) and a full disk; every complete frame received before the fault is in the file.",
        examples="""\
  workbench acquire --port /dev/ttyUSB0 --out datasets/raw/tunnel-2025-03/runs/r0001.loadcell.bin
  workbench acquire --port /dev/ttyUSB0 --baud 921600 --duration 40 --out r0002.loadcell.bin
  workbench acquire --port socket://192.168.1.20:4001 --out r0003.loadcell.bin
  workbench acquire --port /dev/ttyUSB0 --stall-s 2 --out r0004.loadcell.bin   # a silent load cell ends it in 2 s
""")
    p.add_argument("--port", required=True, help="serial device or pyserial URL")
    p.add_argument("--out", type=Path, required=True, help="capture file to create (.bin)")
    p.add_argument("--baud", type=int, default=921600, help="baud rate (default 921600)")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    p.add_argument("--rate-hz", type=float, default=None,
                   help="nominal frame rate, for counting dropped frames (default: from the device counter)")
    p.add_argument("--stall-s", type=float, default=5.0, metavar="S",
                   help="end the recording (exit status 2, capture kept) when no byte arrives for S seconds "
                   "(default 5; 0: wait for ever)")
    p.set_defaults(func=run)


def run(args) -> int:
    """Record with a live progress line on stderr."""
    from workbench.console import info
    from workbench.errors import ContractError
    from workbench.ingest.acquire import AcquisitionFault, record

    if args.stall_s < 0 or args.stall_s != args.stall_s:
        raise ContractError(f"--stall-s must be 0 (off) or a positive number of seconds, not {args.stall_s}")
    if args.out.suffix != ".bin":
        raise ContractError("a capture file ends in .bin", path=args.out)
    tty = sys.stderr.isatty()
    state = {"last": 0.0}

    def show(stats):
        if tty:
            print("\r" + stats.line(), end="", file=sys.stderr, flush=True)
        elif stats.elapsed_s - state["last"] >= 5.0:
            state["last"] = stats.elapsed_s
            info(stats.line())

    info(f"recording {args.port} -> {args.out} (Ctrl-C to stop)")
    try:
        stats = record(args.port, args.out, baudrate=args.baud, duration_s=args.duration, on_progress=show,
                       rate_hz=args.rate_hz, stall_s=args.stall_s or None)
    except AcquisitionFault:
        if tty:
            print(file=sys.stderr)  # end the progress line; the CLI prints the fault's one line
        raise
    if tty:
        print(file=sys.stderr)
    info(f"stopped ({stats.stopped_by}): {stats.line()}; wrote {args.out}")
    return 0
