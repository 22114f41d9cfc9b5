"""Full-body simulator throughput: a batch of 64 EF gaits stepped together vs the same gaits one at a time.

Prints simulated gait-seconds per wall-second for both and their ratio (target: batch >= 20x per gait).
Usage: .venv/bin/python benchmarks/bench_simulator.py [--gaits 64] [--duration 10]
"""

import argparse
import time

import numpy as np

from workbench.hydro.ef import EmpiricalFormula
from workbench.hydro.robot import RobotSettings
from workbench.hydro.simulator import GaitBatch, simulate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gaits", type=int, default=64)
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--repeats", type=int, default=3, help="batch timings to take the best of")
    args = ap.parse_args()

    rng = np.random.default_rng(2025)
    b = args.gaits
    # the paper's optimisation ranges (table II)
    gaits = GaitBatch.from_arrays(rng.uniform(-50, 10, b), rng.uniform(-80, -20, b), rng.uniform(0.2, 0.65, b),
                                  rng.uniform(0, 2 * np.pi, (b, 4)))
    model, robot = EmpiricalFormula(), RobotSettings()
    simulate(gaits.rows(slice(0, 2)), model, robot, duration_s=1.0)  # warm-up (imports, caches)

    batch_s = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        batch = simulate(gaits, model, robot, duration_s=args.duration)
        batch_s.append(time.perf_counter() - t0)
    best = min(batch_s)

    t0 = time.perf_counter()
    iterations = []
    for i in range(b):
        one = simulate(gaits.rows(i), model, robot, duration_s=args.duration)
        iterations.append(one.iterations)
        assert np.allclose(one.y_m[0], batch.y_m[i], atol=1e-12)
    single_s = time.perf_counter() - t0

    gait_seconds = b * args.duration
    batch_rate, single_rate = gait_seconds / best, gait_seconds / single_s
    print(f"simulator: {b} EF gaits x {args.duration:g} s, dt {1000 / 65:.2f} ms, "
          f"{batch.t_s.size} ticks; fixed-point iterations: batch {batch.iterations}, "
          f"single {min(iterations)}-{max(iterations)}")
    print(f"  batch of {b}:   {best:7.3f} s  -> {batch_rate:9.1f} gait-s per wall-s")
    print(f"  one at a time: {single_s:7.3f} s  -> {single_rate:9.1f} gait-s per wall-s")
    ratio = batch_rate / single_rate
    print(f"  ratio: {ratio:.1f}x per gait (target >= 20x): {'OK' if ratio >= 20 else 'BELOW TARGET'}")


if __name__ == "__main__":
    main()
