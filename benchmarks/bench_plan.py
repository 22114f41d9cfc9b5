"""Planned vs random tunnel runs: FED-LSTM ensemble error on the gaits' operating region against tunnel minutes.

    .venv/bin/python benchmarks/bench_plan.py [--rounds 3] [--runs 8] [--members 3] [--out benchmarks/results]

1. An initial campaign (virtual tunnel, rich truth): a small grid far from where the gaits swim
   (theta_h_min in {10, -20, -50}, theta_k_max in {-20, -50, -80}, f in {0.3, 0.45} Hz, phi = pi,
   flow 0 / 0.1 / 0.2 / 0.3 m/s, 3 cycles), ingested, and an ensemble trained on it (its split by
   parameter set is kept for every later training: later runs all train, so no arm loses runs to
   validation or test).
2. Each round, two arms from the same state of their own: **planned** (``plan_campaign`` with the arm's
   current ensemble, ``--runs`` runs) and **random** (runs drawn uniformly within the same rig ranges
   until the planned round's tunnel time is matched), both measured by the virtual tunnel (new noise
   seed per round), ingested, and the arm's ensemble retrained on all its data.
3. Error on the operating region: the ensemble mean against the virtual lab's ground truth
   (``truth_model("rich")``, no rig noise) at the region ticks of the retained gaits, normalised MSE
   (MSE / truth variance over the region) averaged over the six channels. Tunnel time per run:
   cycles / f plus the setup time (pipelines/plan.yaml).

Writes ``bench_plan.json`` and ``bench_plan.png``. One replicate: read differences of a few
per cent as noise.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
GAITS = [ROOT / "datasets/gaits/straight-lstm.json", ROOT / "datasets/gaits/turn-lstm.json"]


def _initial_grid() -> list[dict]:
    out = []
    for h in (10.0, -20.0, -50.0):
        for k in (-20.0, -50.0, -80.0):
            for f in (0.3, 0.45):
                out.append({"theta_h_min_deg": h, "theta_k_max_deg": k, "frequency_hz": f, "phi_rad": math.pi})
    return out


def _region_error(ens, region, truth) -> float:
    rows = np.repeat(np.arange(region.ticks.shape[0]), region.ticks.shape[1])
    cols = region.ticks.ravel()
    y = truth[rows, cols]
    mu, _ = ens.predict(region.motion)
    p = mu[rows, cols]
    w = region.weights.ravel()[:, None] / region.weights.sum()
    mse = (w * (p - y) ** 2).sum(0)
    var = (w * (y - (w * y).sum(0)) ** 2).sum(0)
    return float(np.mean(mse / var))


def _random_plan(ranges, seconds: float, rng, path: Path, cid: str) -> dict:
    """Uniform random runs within the ranges until ``seconds`` of tunnel time are matched (closest)."""
    from workbench.plan.acquisition import Candidate
    from workbench.plan.planner import PlanSettings, manifest_text

    runs, total = [], 0.0
    while True:
        f = rng.uniform(*ranges.frequency_hz)
        sec = ranges.run_seconds(f)
        if total + sec / 2 > seconds:
            break
        c = Candidate(ranges.params(rng.uniform(*ranges.theta_h_min_deg), rng.uniform(*ranges.theta_k_max_deg), f,
                                    rng.uniform(*ranges.phi_rad)),
                      float(rng.choice(ranges.flow_speeds_mps)), ranges.cycles)
        runs.append({"id": f"q{len(runs) + 1:03d}", "flow_speed_mps": c.flow_speed_mps, "params": dict(c.params),
                     "cycles": c.cycles, "tunnel_s": sec})
        total += sec
    rec = {"campaign_id": cid, "runs": runs, "n_runs": len(runs), "tunnel_s": total}
    path.write_text(manifest_text(rec, PlanSettings(ranges=ranges), "2026-01-01"))
    return rec


def main() -> int:  # noqa: C901 - one linear script
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--runs", type=int, default=8, help="planned runs per round")
    ap.add_argument("--members", type=int, default=3)
    ap.add_argument("--epochs", type=int, default=2)
    ap.add_argument("--windows", type=int, default=8000, help="training windows per epoch")
    ap.add_argument("--work", type=Path, default=Path("/tmp/bench_plan"))
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    args = ap.parse_args()

    from workbench.ingest import ingest_to_file
    from workbench.learn.config import load_config
    from workbench.learn.datamodule import prepare_data
    from workbench.learn.ensemble import load_ensemble, train_ensemble
    from workbench.learn.split import ParameterSplit
    from workbench.learn.windows import read_table, set_key
    from workbench.plan.planner import PlanSettings, plan_campaign
    from workbench.plan.region import operating_region
    from workbench.project import load_params
    from workbench.virtual_lab.settings import TunnelSettings
    from workbench.virtual_lab.tunnel import generate_tunnel, truth_model

    t_start = time.perf_counter()
    work = args.work
    if work.exists():
        import shutil

        shutil.rmtree(work)
    (work / "raw").mkdir(parents=True)
    (work / "proc").mkdir()
    settings = PlanSettings.from_dict(load_params(ROOT / "pipelines/plan.yaml", "plan"))
    ranges = settings.ranges
    s = dataclasses.replace(settings, n_candidates=128)
    region = operating_region(GAITS, robot_yaml=ROOT / "pipelines/robot.yaml", duration_s=s.swim_s,
                              cycles=s.region_cycles, points_per_cycle=s.region_points_per_cycle, max_rank=2)
    truth = truth_model("rich", TunnelSettings().physics, []).wrench(region.motion)
    print(f"region: {region.summary()['legs']} legs, {region.summary()['points']} points "
          f"({time.perf_counter() - t_start:.0f} s)", flush=True)

    base_cfg = load_config(ROOT / "pipelines/learn.yaml").with_overrides({
        "tracking.enabled": False, "model_dir": None, "trainer.max_epochs": args.epochs,
        "data.train_windows_per_epoch": args.windows, "trainer.early_stop_patience": 0, "trainer.max_time_s": None})

    def measure(plan_or_grid, name: str, seed: int) -> Path:
        raw = work / "raw" / name
        if isinstance(plan_or_grid, Path):
            generate_tunnel(raw, plan=plan_or_grid, seed=seed)
        else:
            generate_tunnel(raw, grid=plan_or_grid, cycles=3, seed=seed)
        out = work / "proc" / f"{name}.parquet"
        ingest_to_file(raw, out)
        return out

    def split_for(paths: list[Path], first: ParameterSplit) -> ParameterSplit:
        table = read_table(paths)
        assign, params = dict(first.assignment), dict(first.params)
        for row in table.runs.select(list(first.param_columns)).iter_rows(named=True):
            k = set_key(row, first.param_columns)
            if k not in assign:
                assign[k], params[k] = "train", {c: float(row[c]) for c in first.param_columns}
        return ParameterSplit(first.seed, first.fractions, first.param_columns, assign, params, first.pin_test)

    def fit(paths: list[Path], name: str, first: ParameterSplit):
        cfg = base_cfg.with_overrides({"data.paths": [str(p) for p in paths]})
        t0 = time.perf_counter()
        rec = train_ensemble(cfg, work / name, members=args.members, first_seed=100, split=split_for(paths, first))
        ens = load_ensemble(work / name)
        return ens, rec, time.perf_counter() - t0

    p0 = measure(_initial_grid(), "initial", 0)
    first = prepare_data(read_table([p0]), base_cfg.data).split
    setup = ranges.setup_s
    init_minutes = sum(3 / g["frequency_hz"] + setup for g in _initial_grid()) * 4 / 60
    ens0, rec0, fit_s = fit([p0], "ens-initial", first)
    err0 = _region_error(ens0, region, truth)
    print(f"initial: {init_minutes:.1f} tunnel min, region nMSE {err0:.4f}, coverage "
          f"{rec0['calibration'].get('coverage_test_after')} ({fit_s:.0f} s)", flush=True)
    arms = {a: {"paths": [p0], "ens": ens0, "minutes": [init_minutes], "error": [err0], "runs": [0]}
            for a in ("planned", "random")}
    rng = np.random.default_rng(7)
    costs = {"plan_s": [], "fit_s": [fit_s]}
    for r in range(1, args.rounds + 1):
        plan_path = work / f"plan-{r}.toml"
        t0 = time.perf_counter()
        prec = plan_campaign(work / ("ens-initial" if r == 1 else f"ens-planned-{r - 1}"), GAITS, args.runs,
                             plan_path, settings=s, campaign_id=f"planned-{r}", date="2026-01-01", region=region)
        costs["plan_s"].append(time.perf_counter() - t0)
        rand_path = work / f"random-{r}.toml"
        rrec = _random_plan(ranges, prec["tunnel_s"], rng, rand_path, f"random-{r}")
        for arm, path, rec in (("planned", plan_path, prec), ("random", rand_path, rrec)):
            a = arms[arm]
            a["paths"].append(measure(path, f"{arm}-{r}", 100 + r))
            a["ens"], _, fs = fit(a["paths"], f"ens-{arm}-{r}", first)
            costs["fit_s"].append(fs)
            a["minutes"].append(a["minutes"][-1] + rec["tunnel_s"] / 60)
            a["error"].append(_region_error(a["ens"], region, truth))
            a["runs"].append(a["runs"][-1] + rec["n_runs"])
            print(f"round {r} {arm}: +{rec['n_runs']} runs, {a['minutes'][-1]:.1f} tunnel min, region nMSE "
                  f"{a['error'][-1]:.4f}", flush=True)

    result = {
        "description": __doc__.splitlines()[0], "rounds": args.rounds, "runs_per_round": args.runs,
        "members": args.members, "epochs": args.epochs, "windows_per_epoch": args.windows,
        "region": region.summary(), "setup_s": setup, "cycles": ranges.cycles,
        "arms": {k: {m: v[m] for m in ("minutes", "error", "runs")} for k, v in arms.items()},
        "costs": {**costs, "total_s": time.perf_counter() - t_start},
    }
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "bench_plan.json").write_text(json.dumps(result, indent=2) + "\n")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for arm, style in (("planned", "o-"), ("random", "s--")):
        ax.plot(arms[arm]["minutes"], arms[arm]["error"], style, label=arm)
    ax.set_xlabel("tunnel minutes (cycles / f + setup per run)")
    ax.set_ylabel("ensemble nMSE on the gaits' operating region")
    ax.set_title("planned vs random runs (virtual tunnel, rich truth)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(args.out / "bench_plan.png", dpi=100)
    print(json.dumps(result["arms"], indent=1))
    print(f"total {result['costs']['total_s']:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
