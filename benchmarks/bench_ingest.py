"""Ingest speed at paper scale against a plain polars read of the same CSV bytes.

Targets (foundation issue, section 7): ingest within 3x of the plain read, a paper-scale
campaign in under 60 s on 2 cores, peak memory under 4 GB.

    .venv/bin/python benchmarks/bench_ingest.py                 # paper scale (generated once, ~2 GB)
    .venv/bin/python benchmarks/bench_ingest.py --scale demo    # the demo campaign, quick

The campaign comes from the virtual lab (``generate_tunnel(scale=...)``, CSV pairs) and is
cached under build/bench/ (gitignored). Both timings read the same files from a warm page
cache. The plain read is polars at its best (one multi-threaded scan per file kind) and, for
reference, one ``read_csv`` per file. Ingest runs as the real command (``workbench ingest
--force``) in a child process; its peak memory is the largest total RSS of its process tree.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def ensure_campaign(scale: str, folder: Path, regenerate: bool) -> Path:
    target = folder / f"{scale}-tunnel"
    if target.is_dir() and not regenerate and (target / "campaign.toml").is_file():
        return target
    from workbench.virtual_lab.tunnel import generate_tunnel

    print(f"generating the {scale}-scale tunnel campaign in {target} (once; cached) ...", flush=True)
    t0 = time.perf_counter()
    if target.exists():
        import shutil

        shutil.rmtree(target)
    generate_tunnel(target, scale=scale, form="csv", seed=0, campaign_id=target.name, show_progress=True)
    print(f"  generated in {time.perf_counter() - t0:.0f} s", flush=True)
    return target


def warm(files: list[Path]) -> int:
    total = 0
    for f in files:
        total += len(f.read_bytes())
    return total


def plain_read(runs: Path) -> tuple[float, int, float, float]:
    """(seconds for the best scan, rows, seconds for one read_csv per file, CPU seconds of the scan)."""
    import polars as pl

    c0 = time.process_time()
    t0 = time.perf_counter()
    rows = 0
    for kind in ("loadcell", "motion"):
        rows += pl.scan_csv(str(runs / f"*.{kind}.csv")).select(pl.len()).collect().item() * 0  # warm planner
        df = pl.scan_csv(str(runs / f"*.{kind}.csv")).collect()
        rows += df.height
        del df
    scan_s = time.perf_counter() - t0
    scan_cpu = time.process_time() - c0
    t0 = time.perf_counter()
    for f in sorted(runs.glob("*.csv")):
        pl.read_csv(f)
    per_file_s = time.perf_counter() - t0
    return scan_s, rows, per_file_s, scan_cpu


def tree_rss_bytes(pid: int) -> int:
    """Resident memory of a process and all its descendants (Linux /proc)."""
    total, stack = 0, [pid]
    while stack:
        p = stack.pop()
        try:
            with open(f"/proc/{p}/status") as fh:
                for line in fh:
                    if line.startswith("VmRSS:"):
                        total += int(line.split()[1]) * 1024
            for task in os.listdir(f"/proc/{p}/task"):
                with open(f"/proc/{p}/task/{task}/children") as fh:
                    stack.extend(int(c) for c in fh.read().split())
        except (FileNotFoundError, ProcessLookupError, PermissionError):
            continue
    return total


def run_ingest(campaign: Path, out: Path, workers: int) -> tuple[float, int, str, float]:
    cmd = [sys.executable, "-m", "workbench.cli", "ingest", str(campaign), "--out", str(out), "--force",
           "--quiet", "--workers", str(workers)]
    peak = [0]
    import resource

    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    def sample():
        while proc.poll() is None:
            peak[0] = max(peak[0], tree_rss_bytes(proc.pid))
            time.sleep(0.05)

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    _, err = proc.communicate()
    wall = time.perf_counter() - t0
    sampler.join()
    if proc.returncode != 0:
        raise SystemExit(f"ingest failed:\n{err}")
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    return wall, peak[0], err.strip().splitlines()[-1] if err.strip() else "", cpu


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scale", default="paper", choices=("paper", "demo"))
    ap.add_argument("--data", type=Path, default=ROOT / "build" / "bench")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--regenerate", action="store_true")
    args = ap.parse_args()
    campaign = ensure_campaign(args.scale, args.data, args.regenerate)
    runs = campaign / "runs"
    files = sorted(runs.glob("*.csv"))
    nbytes = warm(files)
    print(f"campaign {campaign.name}: {len(files)} CSV files, {nbytes / 1e6:.0f} MB; load average "
          f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores", flush=True)
    scan_s, rows, per_file_s, scan_cpu = plain_read(runs)
    out = args.data / f"{campaign.name}.parquet"
    wall, peak, summary, cpu = run_ingest(campaign, out, args.workers)
    baseline = min(scan_s, per_file_s)
    print(f"plain polars read (scan per kind): {scan_s:7.2f} s  {rows / scan_s / 1e6:6.2f} M rows/s")
    print(f"plain polars read (file by file):  {per_file_s:7.2f} s  {rows / per_file_s / 1e6:6.2f} M rows/s")
    print(f"workbench ingest ({args.workers} threads):      {wall:7.2f} s  {rows / wall / 1e6:6.2f} M rows/s"
          f"   ({summary})")
    ratio = wall / baseline
    print(f"ratio ingest / fastest plain read: {ratio:.2f}   (target <= 3)")
    print(f"CPU seconds: ingest {cpu:.1f}, plain scan {scan_cpu:.1f}, ratio {cpu / scan_cpu:.2f} "
          "(independent of other load on the machine)")
    print(f"ingest wall time:                  {wall:.1f} s  (target < 60 s at paper scale)")
    print(f"ingest peak memory (process tree): {peak / 2 ** 30:.2f} GB  (target < 4 GB)")
    ok = ratio <= 3 and (args.scale != "paper" or wall < 60) and peak < 4 * 2 ** 30
    print("targets met" if ok else "TARGETS MISSED")
    return 0


if __name__ == "__main__":
    sys.exit(main())
