"""Gait optimisation with the FED-LSTM: tabulated leg wrenches against the direct rollout, same run.

Runs ``workbench optimize``'s domain function for straight and turn at the ``benchmark`` settings
of pipelines/gait.yaml (population 64, 50 generations; 20 s swims) with leg wrenches tabulated
per gait shape, including its final check: the best ``verify_direct`` gaits swum again with the
direct rollout (the LSTM on every tick of every leg in every fixed-point iteration). The direct
rollout of the whole budget takes hours on 2 cores, so its time is extrapolated per gait from
that check (its cost is per gait), whose swims also give the accuracy of the tables on the real
model. Target: both tasks in under 10 minutes on 2 cores; prints the speed-up.

    .venv/bin/python benchmarks/bench_optimize.py                 # the registered FED-LSTM ("lstm")
    .venv/bin/python benchmarks/bench_optimize.py --gens 5        # a quick look
    .venv/bin/python benchmarks/bench_optimize.py --model random  # the paper-sized LSTM, untrained

``--workers-compare`` times the same paper-scale search (population 64, the pipeline's 60 s turn
task, FED-LSTM tabulated, ``--gens`` generations, the direct check of the best ``--verify``) three
ways: two simulator worker processes with one torch thread each, one process with one thread,
one process with two threads; it prints wall and CPU time, the ratios, the load average
and whether the three runs' populations and kept gaits are identical:

    .venv/bin/python benchmarks/bench_optimize.py --workers-compare --model datasets/models/fed-lstm --gens 2
"""

from __future__ import annotations

import argparse
import json
import time


def untrained_fed_lstm():
    """The paper's FED-LSTM architecture (2 x 64, 16 ticks) with random weights: the same inference cost."""
    import torch

    from workbench.learn.config import ModelSettings
    from workbench.learn.legmodel import LearnedLegModel
    from workbench.learn.nets import build_net
    from workbench.learn.windows import Normalisation

    torch.manual_seed(0)
    cfg = ModelSettings(variant="ef_residual", hidden_size=64, num_layers=2, dropout=0.21)
    norm = Normalisation((0.1, -45.0, 0.0, 0.0, 0.0), (0.1, 30.0, 50.0, 100.0, 200.0), (0.0,) * 6,
                         (0.05, 0.05, 0.05, 0.005, 0.005, 0.005))
    return LearnedLegModel(build_net(cfg, 16), model=cfg, seq_len=16, dt_s=1 / 65, norm=norm, name="lstm")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default="lstm", help="leg model spec, or 'random' for an untrained FED-LSTM")
    ap.add_argument("--params", default="pipelines/gait.yaml")
    ap.add_argument("--gens", type=int, default=None)
    ap.add_argument("--pop", type=int, default=None)
    ap.add_argument("--json", default=None, help="also write the numbers to this JSON file")
    ap.add_argument("--workers-compare", action="store_true",
                    help="1 process x 1 thread, 1 x 2 threads, 2 worker processes x 1 thread on the same search")
    ap.add_argument("--verify", type=int, default=16, help="--workers-compare: gaits in the direct check")
    ap.add_argument("--ways", type=int, default=3, choices=(1, 2, 3),
                    help="--workers-compare: 2 workers only, and 1 x 1 thread, and 1 x 2 threads")
    ap.add_argument("--task", default="turn", choices=("turn", "straight"), help="--workers-compare: the task")
    args = ap.parse_args()
    if args.workers_compare:
        compare_workers(args)
        return

    import torch

    from workbench.gait.config import config_from_dict
    from workbench.gait.optimize import optimize_task
    from workbench.hydro.legmodel import load_leg_model
    from workbench.hydro.robot import load_robot
    from workbench.project import load_params
    from workbench.threads import apply_torch_threads

    doc = load_params(args.params)
    bench = dict(doc.get("benchmark") or {})
    opt = dict(doc["optimize"])
    opt["nsga2"] = {**opt.get("nsga2", {}), **bench.get("nsga2", {})}
    opt["tasks"] = {k: {**opt["tasks"][k], **v} for k, v in bench.get("tasks", {}).items()}
    opt["verify_direct"] = bench.get("verify_direct", opt.get("verify_direct", 16))
    cfg = config_from_dict(opt, args.params).with_overrides(pop_size=args.pop, n_gen=args.gens)
    apply_torch_threads(cfg.torch_threads)
    model = untrained_fed_lstm() if args.model == "random" else load_leg_model(args.model)
    robot = load_robot(cfg.robot)
    print(f"model {args.model!r} ({model.describe().get('variant', '?')}), torch threads {torch.get_num_threads()}, "
          f"NSGA-II {cfg.nsga2.pop_size} x {cfg.nsga2.n_gen} per task, {cfg.verify_direct} gaits re-swum directly")

    rows = {}
    for task in ("straight", "turn"):
        def show(g, task=task):
            if g.gen % 10 == 0 or g.gen == 1:
                print(f"  {task} gen {g.gen:3d} evals {g.evaluations:5d} best S {g.best_score:8.3f} "
                      f"HV {g.hypervolume:.4g} ({g.seconds:.0f} s)", flush=True)

        t0 = time.perf_counter()
        o = optimize_task(cfg, task, model, robot, model_label="lstm", on_generation=show, plots=False)
        total = time.perf_counter() - t0
        m = o.metrics
        n_dir = m.get("verified_direct", 0)
        per_gait = m["verify_seconds"] / n_dir if n_dir else float("nan")
        rows[task] = {"evaluations": m["evaluations"], "total_s": total, "search_s": total - m.get("verify_seconds", 0),
                      "direct_gaits": n_dir, "direct_s": m.get("verify_seconds"),
                      "direct_extrapolated_s": per_gait * m["evaluations"],
                      "best_score": m["best_score"], "max_rel_diff_f1_f2_f3": m.get("verify_max_rel_diff"),
                      "max_rel_diff_score": m.get("verify_max_rel_diff_score"), "table": m["tabulation"],
                      "unconverged": m["unconverged_gaits"]}
        r = rows[task]
        diff = ", ".join(f"f{i + 1} {v:.2%}" for i, v in enumerate(r["max_rel_diff_f1_f2_f3"] or []))
        print(f"{task}: {total:.0f} s in all ({r['search_s']:.0f} s tabulated search of {m['evaluations']} gaits, "
              f"{r['direct_s']:.0f} s direct rollout of the best {n_dir}); the direct rollout of the whole budget: "
              f"{r['direct_extrapolated_s'] / 3600:.2f} h; tabulated vs direct on the best {n_dir}: {diff}, "
              f"S {r['max_rel_diff_score']:.2%}", flush=True)
    total_tab = sum(r["total_s"] for r in rows.values())
    total_dir = sum(r["direct_extrapolated_s"] for r in rows.values())
    summary = {"model": args.model, "pop_size": cfg.nsga2.pop_size, "n_gen": cfg.nsga2.n_gen,
               "tabulated_total_s": total_tab, "direct_total_extrapolated_s": total_dir,
               "speedup": total_dir / total_tab, "target_s": 600.0, "tasks": rows}
    print(f"\nstraight + turn, LSTM, population {cfg.nsga2.pop_size} x {cfg.nsga2.n_gen} generations: "
          f"{total_tab:.0f} s with tabulated wrenches and the direct check (target < 600 s: "
          f"{'met' if total_tab < 600 else 'MISSED'}); direct rollout of the same budget {total_dir / 3600:.2f} h "
          f"(extrapolated per gait from the direct check); speed-up {total_dir / total_tab:.0f}x")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(summary, fh, indent=2)


def _cpu_s() -> float:
    """CPU seconds (user + system) of this process and its ended children (the workers, once their pool closed)."""
    import resource

    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def compare_workers(args) -> None:
    """The same search three ways (see the module text); prints a table and writes --json."""
    import os
    from dataclasses import replace

    import numpy as np
    import torch

    from workbench.gait.config import load_config
    from workbench.gait.optimize import optimize_task
    from workbench.hydro.legmodel import load_leg_model
    from workbench.hydro.robot import load_robot

    cfg = load_config(args.params).with_overrides(pop_size=args.pop or 64, n_gen=args.gens or 3)
    cfg = replace(cfg, verify_direct=args.verify, retain=min(8, args.verify))
    model = untrained_fed_lstm() if args.model == "random" else load_leg_model(args.model)
    drag = "datasets/drag/demo-towing/drag.json"
    robot = load_robot(cfg.robot, drag_json=drag if os.path.exists(drag) else cfg.drag_json)
    ways = [("2 worker processes, 1 thread each", 2, 2), ("1 process, 1 torch thread", 1, 1),
            ("1 process, 2 torch threads", 1, 2)][:args.ways]
    print(f"{args.task}: NSGA-II {cfg.nsga2.pop_size} x {cfg.nsga2.n_gen}, {cfg.task(args.task).spec.cap_s:g} s swims, "
          f"direct check of {cfg.verify_direct}; model {args.model!r}; {os.cpu_count()} cores", flush=True)
    rows, outs = [], []
    for name, workers, threads in ways:
        torch.set_num_threads(threads)
        load0, c0, t0 = os.getloadavg()[0], _cpu_s(), time.perf_counter()
        o = optimize_task(cfg, args.task, model, robot, model_label="lstm", plots=False, workers=workers)
        wall, cpu = time.perf_counter() - t0, _cpu_s() - c0
        m = o.metrics
        rows.append({"way": name, "workers": workers, "torch_threads_per_process": max(1, threads // workers), "wall_s": wall, "cpu_s": cpu,
                     "search_wall_s": m["simulation_seconds"], "verify_wall_s": m.get("verify_seconds", 0.0),
                     "load_start": load0, "load_end": os.getloadavg()[0], "best_score": m["best_score"],
                     "workers_cpu_s": m.get("workers_cpu_s"), "workers_busiest_cpu_s": m.get("workers_busiest_cpu_s")})
        outs.append(o)
        if workers > 1:  # load-independent: the parts' CPU seconds, all of them and the busiest part of each batch
            print(f"    workers' CPU {m['workers_cpu_s']:.0f} s, on the critical path {m['workers_busiest_cpu_s']:.0f} s: "
                  f"on idle cores the swims run {m['workers_cpu_s'] / m['workers_busiest_cpu_s']:.2f}x faster than in "
                  f"one process", flush=True)
        if args.json:
            with open(args.json, "w", encoding="utf-8") as fh:
                json.dump({"rows": rows}, fh, indent=2)
        print(f"  {name}: {wall:.0f} s wall ({m['simulation_seconds']:.0f} s search, {m.get('verify_seconds', 0):.0f} s "
              f"direct check), {cpu:.0f} s CPU, load {load0:.1f} -> {os.getloadavg()[0]:.1f}", flush=True)
    ref = 1 if len(rows) > 1 else 0  # one process, one thread
    for r, o in zip(rows, outs, strict=True):
        r["speedup_wall"] = rows[ref]["wall_s"] / r["wall_s"]
        r["same_population"] = bool(np.array_equal(o.result.f, outs[ref].result.f))
        r["same_kept_gaits"] = bool(np.array_equal(o.retained.x, outs[ref].retained.x)
                                    and np.array_equal(o.retained.f, outs[ref].retained.f))
        r["max_abs_diff_f"] = float(np.abs(o.result.f - outs[ref].result.f).max())
    print("\n| way | wall (s) | search (s) | direct check (s) | CPU (s) | wall speed-up | load at start | identical |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        same = "yes" if r["same_population"] and r["same_kept_gaits"] else f"no (max |df| {r['max_abs_diff_f']:.1e})"
        print(f"| {r['way']} | {r['wall_s']:.0f} | {r['search_wall_s']:.0f} | {r['verify_wall_s']:.0f} | "
              f"{r['cpu_s']:.0f} | {r['speedup_wall']:.2f} | {r['load_start']:.1f} | {same} |")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump({"task": args.task, "pop_size": cfg.nsga2.pop_size, "n_gen": cfg.nsga2.n_gen,
                       "verify_direct": cfg.verify_direct, "model": args.model, "rows": rows}, fh, indent=2)


if __name__ == "__main__":
    main()
