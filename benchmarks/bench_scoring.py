"""Scoring speed against decoding alone, on the same virtual-pool videos in the same run.

For 960x540 and 1280x720 at 30 fps, renders a straight run and a turn (about 25 s each), then
measures frames per second of (a) decode-only (cv2.VideoCapture.read of every frame) and (b) the
scorer (decode + detection + tracking + cleaning + scoring, no overlay, no early stop), both for
one process and for two processes over the trials (the "2 cores" figure). Prints the ratio and
the real-time factor at 30 fps (target: scoring >= 10x real time, i.e. >= 300 frames/s).

    .venv/bin/python benchmarks/bench_scoring.py            # about a minute
    .venv/bin/python benchmarks/bench_scoring.py --seconds 12 --sizes 960x540
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path


def decode_all(path: str) -> int:
    import cv2

    cap = cv2.VideoCapture(path)
    n = 0
    while True:
        ok, _ = cap.read()
        if not ok:
            break
        n += 1
    cap.release()
    return n


def score_one(args) -> int:
    root, tid = args
    from workbench.contract.trials import load_trials
    from workbench.trials import ScoringSettings, score_trial

    folder, _ = load_trials(root)
    p = ScoringSettings(early_stop=False, overlay=False, pre_start_s=10.0)
    return score_trial(folder.trial(tid), folder.robot, p).stats["frames_decoded"]


def render(root: Path, w: int, h: int, seconds: float) -> Path:
    from workbench.virtual_lab.pool import PoolSettings, PoolTrial, circle_path, generate_pool, straight_path

    s = PoolSettings(width_px=w, height_px=h, fps=30.0, seed=1, occlusion_fraction=1.0, post_s=0.5, workers=2)
    t1 = PoolTrial("straight", "straight", "EF", 1, *straight_path(speed_mps=2.6 / seconds, duration_s=seconds))
    t2 = PoolTrial("turn", "turn", "EF", 1, *circle_path(radius_m=0.1, period_s=seconds - 3, duration_s=seconds))
    return generate_pool(root / f"pool-{w}x{h}", [t1, t2], settings=s, progress=False)


def warm() -> None:
    """Import everything the scorer uses, so no import time is measured."""
    import cv2  # noqa: F401
    import polars  # noqa: F401
    import scipy.interpolate  # noqa: F401
    import scipy.optimize  # noqa: F401
    import scipy.signal  # noqa: F401

    import workbench.trials  # noqa: F401


def timed(fn, jobs, workers: int, repeats: int) -> tuple[int, float]:
    """Frames and the best wall time over ``repeats`` runs of ``fn`` over ``jobs`` in ``workers`` processes."""
    best, n = float("inf"), 0
    if workers == 1:
        for _ in range(repeats):
            t0 = time.perf_counter()
            n = sum(fn(j) for j in jobs)
            best = min(best, time.perf_counter() - t0)
        return n, best
    with ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"), initializer=warm) as ex:
        list(ex.map(time.sleep, [0.5] * workers))  # all workers up and warm before the clock runs
        for _ in range(repeats):
            t0 = time.perf_counter()
            n = sum(ex.map(fn, jobs))
            best = min(best, time.perf_counter() - t0)
    return n, best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", nargs="+", default=["960x540", "1280x720"])
    ap.add_argument("--seconds", type=float, default=25.0, help="length of each rendered trial")
    ap.add_argument("--repeats", type=int, default=3, help="best of this many timings (the machine is shared)")
    args = ap.parse_args()
    import cv2

    print(f"OpenCV {cv2.__version__}, {cv2.getNumberOfCPUs()} CPUs")
    print(f"{'size':>10} {'procs':>5} {'decode fps':>11} {'score fps':>10} {'score/decode':>13} {'x real time@30':>15}")
    with tempfile.TemporaryDirectory() as tmp:
        for size in args.sizes:
            w, h = (int(v) for v in size.split("x"))
            root = render(Path(tmp), w, h, args.seconds)
            videos = [str(root / "videos" / f"{t}.mp4") for t in ("straight", "turn")]
            jobs = [(str(root), t) for t in ("straight", "turn")]
            warm()
            score_one(jobs[0])  # warm caches
            for procs in (1, 2):
                n_dec, t_dec = timed(decode_all, videos, procs, args.repeats)
                n_sc, t_sc = timed(score_one, jobs, procs, args.repeats)
                dec, sc = n_dec / t_dec, n_sc / t_sc
                print(f"{size:>10} {procs:>5} {dec:11.0f} {sc:10.0f} {sc / dec:13.2f} {sc / 30:15.1f}")


if __name__ == "__main__":
    main()
