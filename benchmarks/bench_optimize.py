"""Gait optimisation with the FED-LSTM: tabulated leg wrenches against the direct rollout, same run.

Runs NSGA-II for straight and turn at the ``benchmark`` settings of pipelines/gait.yaml (population
64, 50 generations; 20 s swims) with leg wrenches tabulated per gait shape, and times the direct
rollout (the LSTM on every tick of every leg in every fixed-point iteration) of the same budget:
the direct rollout of a full budget takes hours on 2 cores, so it is timed on ``direct_gaits``
gaits per task (the best of each optimisation, whose swims also give the accuracy of tabulation
on the real model) and extrapolated linearly in the number of gaits (its cost is per gait).
Target: both tasks tabulated in under 10 minutes on 2 cores; prints the speed-up.

    .venv/bin/python benchmarks/bench_optimize.py                 # the registered FED-LSTM ("lstm")
    .venv/bin/python benchmarks/bench_optimize.py --gens 5        # a quick look
    .venv/bin/python benchmarks/bench_optimize.py --model random  # the paper-sized LSTM, untrained
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace

import numpy as np


def untrained_fed_lstm():
    """The paper's FED-LSTM architecture (2 x 64, 16 ticks) with random weights: the same inference cost."""
    import torch

    from workbench.learn.config import ModelCfg
    from workbench.learn.legmodel import LearnedLegModel
    from workbench.learn.nets import build_net
    from workbench.learn.windows import Normalisation

    torch.manual_seed(0)
    cfg = ModelCfg(variant="ef_residual", hidden_size=64, num_layers=2, dropout=0.21)
    norm = Normalisation((0.1, -45.0, 0.0, 0.0, 0.0), (0.1, 30.0, 50.0, 100.0, 200.0), (0.0,) * 6,
                         (0.05, 0.05, 0.05, 0.005, 0.005, 0.005))
    return LearnedLegModel(build_net(cfg, 16), model=cfg, seq_len=16, dt_s=1 / 65, norm=norm, name="lstm")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default="lstm", help="leg model spec, or 'random' for an untrained FED-LSTM")
    ap.add_argument("--params", default="pipelines/gait.yaml")
    ap.add_argument("--gens", type=int, default=None)
    ap.add_argument("--pop", type=int, default=None)
    ap.add_argument("--direct-gaits", type=int, default=None)
    ap.add_argument("--json", default=None, help="also write the numbers to this JSON file")
    args = ap.parse_args()

    import torch

    from workbench.gait.config import config_from_dict
    from workbench.gait.optimize import relative_difference
    from workbench.gait.problem import GaitProblem
    from workbench.gait.run import run_nsga2
    from workbench.hydro.legmodel import load_leg_model
    from workbench.hydro.robot import load_robot
    from workbench.project import load_params

    doc = load_params(args.params)
    bench = dict(doc.get("benchmark") or {})
    opt = dict(doc["optimize"])
    opt["nsga2"] = {**opt.get("nsga2", {}), **bench.get("nsga2", {})}
    opt["tasks"] = {k: {**opt["tasks"][k], **v} for k, v in bench.get("tasks", {}).items()}
    cfg = config_from_dict(opt, args.params).with_overrides(pop_size=args.pop, n_gen=args.gens)
    n_direct = args.direct_gaits or int(bench.get("direct_gaits", 8))
    if cfg.torch_threads:
        torch.set_num_threads(cfg.torch_threads)
    model = untrained_fed_lstm() if args.model == "random" else load_leg_model(args.model)
    robot = load_robot(cfg.robot)
    print(f"model {args.model!r} ({model.describe().get('variant', '?')}), torch threads {torch.get_num_threads()}, "
          f"NSGA-II {cfg.nsga2.pop_size} x {cfg.nsga2.n_gen} per task")

    rows = {}
    t_all = time.perf_counter()
    for task in ("straight", "turn"):
        ts = cfg.task(task)
        problem = GaitProblem(ts.spec, model, robot, space=cfg.space, sim=cfg.simulation, tabulation=cfg.tabulation)
        t0 = time.perf_counter()
        res = run_nsga2(problem, cfg.nsga2, ts.hv_reference,
                        on_generation=lambda g, task=task: print(
                            f"  {task} gen {g.gen:3d} evals {g.evaluations:5d} best S {g.best_score:8.3f} "
                            f"HV {g.hypervolume:.4g} ({g.seconds:.0f} s)", flush=True)
                        if g.gen % 10 == 0 or g.gen == 1 else None)
        tab_s = time.perf_counter() - t0
        # the same gaits through the tabulated and the direct rollout
        best = problem.space.gaits(res.x[:n_direct])
        t1 = time.perf_counter()
        f_tab = problem.evaluate_gaits(best)[0]
        tab_small_s = time.perf_counter() - t1
        direct = GaitProblem(ts.spec, model, robot, space=cfg.space, sim=cfg.simulation,
                             tabulation=replace(cfg.tabulation, mode="never"))
        t1 = time.perf_counter()
        f_dir = direct.evaluate_gaits(best)[0]
        direct_s = time.perf_counter() - t1
        floors = np.array([0.05, 0.05, 1.0]) if task == "straight" else np.array([0.1, 0.05, 1.0])
        rel = np.abs(f_tab - f_dir) / np.maximum(np.abs(f_dir), floors)
        s_rel = relative_difference(f_tab @ np.asarray(ts.spec.weights), f_dir @ np.asarray(ts.spec.weights))
        per_gait_direct = direct_s / n_direct
        rows[task] = {
            "evaluations": res.evaluations, "tabulated_s": tab_s, "direct_measured_gaits": n_direct,
            "direct_measured_s": direct_s, "direct_extrapolated_s": per_gait_direct * res.evaluations,
            "tabulated_same_gaits_s": tab_small_s, "best_score": float(res.s[0]),
            "max_rel_diff_f1_f2_f3": [float(v) for v in rel.max(axis=0)], "max_rel_diff_score": s_rel,
            "table": dict(problem.log.table), "unconverged": problem.log.unconverged,
        }
        print(f"{task}: tabulated {tab_s:.0f} s for {res.evaluations} evaluations; direct rollout "
              f"{direct_s:.0f} s for {n_direct} gaits -> {rows[task]['direct_extrapolated_s'] / 3600:.1f} h for the "
              f"budget; objectives of the best {n_direct}: max rel. diff f1 {rel[:, 0].max():.2%}, "
              f"f2 {rel[:, 1].max():.2%}, f3 {rel[:, 2].max():.2%}, S {s_rel:.2%}", flush=True)
    total_tab = sum(r["tabulated_s"] for r in rows.values())
    total_dir = sum(r["direct_extrapolated_s"] for r in rows.values())
    summary = {"model": args.model, "pop_size": cfg.nsga2.pop_size, "n_gen": cfg.nsga2.n_gen,
               "tabulated_total_s": total_tab, "direct_total_extrapolated_s": total_dir,
               "speedup": total_dir / total_tab, "target_s": 600.0, "wall_s": time.perf_counter() - t_all,
               "tasks": rows}
    print(f"\nstraight + turn, LSTM, population {cfg.nsga2.pop_size} x {cfg.nsga2.n_gen} generations: "
          f"tabulated {total_tab:.0f} s (target < 600 s: {'met' if total_tab < 600 else 'MISSED'}), "
          f"direct rollout {total_dir / 3600:.1f} h (extrapolated from {n_direct} gaits per task), "
          f"speed-up {total_dir / total_tab:.0f}x")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(summary, fh, indent=2)


if __name__ == "__main__":
    main()
