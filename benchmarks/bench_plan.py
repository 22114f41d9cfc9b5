"""Planned vs random vs grid tunnel runs: FED-LSTM ensemble error on the gaits' operating region against tunnel minutes.

    .venv/bin/python benchmarks/bench_plan.py [--seeds 0 1 2] [--rounds 3] [--runs 8] [--members 3]
        [--epochs 2] [--windows 4000] [--work /tmp/bench_plan] [--out benchmarks/results]
    .venv/bin/python benchmarks/bench_plan.py --aggregate-only --work DIR     # rewrite json/png from seed files

Per seed (the seed sets the initial campaign's rig noise and split, the ensembles' member seeds, the
planner's candidate pool, the random draws, the grid's order and every round's rig noise):

1. An initial campaign (virtual tunnel, rich truth): a small grid far from where the gaits swim
   (theta_h_min in {10, -50}, theta_k_max in {-20, -80}, f in {0.3, 0.45} Hz, phi = pi,
   flow 0 / 0.1 / 0.2 / 0.3 m/s, 3 cycles), ingested, and an ensemble trained on it (its split by
   parameter set is kept for every later training: later runs all train, so no arm loses runs to
   validation or test).
2. Each round, three arms from the same state of their own: **planned** (``plan_from_files`` with the
   arm's current ensemble, ``--runs`` runs), **random** (runs drawn uniformly within the same rig
   ranges) and **grid** (a fixed 3 x 3 x 3 x 3 grid of the rig ranges, each parameter set at the 4
   flow speeds 0 / 0.1 / 0.2 / 0.3 m/s as the paper measured, parameter sets in a seeded order),
   the last two until the planned round's tunnel time is matched (closest); all measured by the
   virtual tunnel (the same noise seed per round), ingested, and the arm's ensemble retrained on all
   its data.
3. Error on the operating region: the ensemble mean against the virtual lab's ground truth
   (``truth_model("rich")``, no rig noise) at the region ticks of the retained gaits, normalised MSE
   (MSE / truth variance over the region) averaged over the six channels. The region is swum with
   each gait file's own model (the FED-LSTM, tabulated as the optimiser does); the EF-legs region is
   computed too and their difference recorded. Tunnel time per run: cycles / f plus the setup time
   (pipelines/plan.yaml).

Seeds may run in separate processes sharing WORK (``--seeds 0 1`` and ``--seeds 2``). Each seed
writes ``WORK/seed-<n>.json`` when done (an older one of the same seed is replaced); after each seed ``bench_plan.json`` and
``bench_plan.png`` are rewritten from all seed files in WORK (mean and min-max band over seeds), with
the tunnel time the planned arm needs to reach the random (and grid) arm's final error.
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
ARMS = ("planned", "random", "grid")
GRID_FLOWS = (0.0, 0.1, 0.2, 0.3)


def _initial_grid() -> list[dict]:
    out = []
    for h in (10.0, -50.0):
        for k in (-20.0, -80.0):
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


def _take(cands, ranges, seconds: float, path: Path, cid: str) -> dict:
    """Runs from ``cands`` in order until ``seconds`` of tunnel time are matched (closest); writes the manifest."""
    from workbench.plan.planner import PlanSettings, manifest_text

    runs, total = [], 0.0
    for c in cands:
        sec = ranges.run_seconds(c.params["frequency_hz"], c.cycles)
        if total + sec / 2 > seconds:
            break
        runs.append({"id": f"q{len(runs) + 1:03d}", "flow_speed_mps": c.flow_speed_mps, "params": dict(c.params),
                     "cycles": c.cycles, "tunnel_s": sec})
        total += sec
    rec = {"campaign_id": cid, "runs": runs, "n_runs": len(runs), "tunnel_s": total}
    path.write_text(manifest_text(rec, PlanSettings(ranges=ranges), "2026-01-01"))
    return rec


def _random_stream(ranges, rng):
    """Uniform random runs within the ranges, one flow speed of the rig's list each (endless)."""
    from workbench.plan.acquisition import Candidate

    while True:
        f = rng.uniform(*ranges.frequency_hz)
        yield Candidate(ranges.params(rng.uniform(*ranges.theta_h_min_deg), rng.uniform(*ranges.theta_k_max_deg), f,
                                      rng.uniform(*ranges.phi_rad)),
                        float(rng.choice(ranges.flow_speeds_mps)), ranges.cycles)


def _grid_runs(ranges, rng) -> list:
    """The 3^4 grid of the ranges (ends and middle), parameter sets in a seeded order, each at GRID_FLOWS."""
    import itertools

    from workbench.plan.acquisition import Candidate

    def lv(r):
        return (r[0], 0.5 * (r[0] + r[1]), r[1])

    sets = list(itertools.product(lv(ranges.theta_h_min_deg), lv(ranges.theta_k_max_deg), lv(ranges.frequency_hz),
                                  lv(ranges.phi_rad)))
    order = rng.permutation(len(sets))
    return [Candidate(ranges.params(*sets[i]), u, ranges.cycles) for i in order for u in GRID_FLOWS]


def _regions(settings):
    """The operating region with the gait files' own legs (used) and with EF legs (compared)."""
    from workbench.commands.plan_campaign import own_legs, read_gait_files
    from workbench.hydro.robot import load_robot
    from workbench.plan.region import operating_region

    files, robot = read_gait_files(GAITS, max_rank=2), load_robot(ROOT / "pipelines/robot.yaml")
    kw = dict(duration_s=settings.swim_s, cycles=settings.region_cycles,
              points_per_cycle=settings.region_points_per_cycle)
    own = operating_region(files, robot, legs=own_legs(root=ROOT), **kw)
    ef = operating_region(files, robot, **kw)
    so, se = own.states(), ef.states()
    names = ("flow_speed_mps", "theta_h_deg", "theta_k_deg", "omega_h_dps", "omega_k_dps")
    cmp = {"own_legs": own.summary(), "ef_legs": ef.summary(),
           "leg_flow_mean_mps": {"own": float(so[:, 0].mean()), "ef": float(se[:, 0].mean())},
           "mean_abs_difference": {k: float(np.abs(so[:, i] - se[:, i]).mean()) for i, k in enumerate(names)},
           "max_abs_difference": {k: float(np.abs(so[:, i] - se[:, i]).max()) for i, k in enumerate(names)},
           "swim_s": {"own": own.swim_s, "ef": ef.swim_s}}
    return own, ef, cmp


def run_seed(seed: int, args, settings, region, truth, ef_region, ef_truth) -> dict:  # noqa: C901 - one protocol
    import shutil

    from workbench.commands.plan_campaign import plan_from_files
    from workbench.commands.train_ensemble import write_ensemble
    from workbench.ingest import ingest_to_file
    from workbench.learn.config import load_config
    from workbench.learn.datamodule import prepare_data
    from workbench.learn.ensemble import load_ensemble, train_ensemble
    from workbench.learn.split import ParameterSplit
    from workbench.learn.windows import read_table, set_key
    from workbench.virtual_lab.tunnel import generate_tunnel

    t_start = time.perf_counter()
    work = args.work / f"seed-{seed}"
    if work.exists():
        shutil.rmtree(work)
    (work / "raw").mkdir(parents=True)
    (work / "proc").mkdir()
    ranges = settings.ranges
    s = dataclasses.replace(settings, n_candidates=args.candidates, seed=seed)
    base_cfg = load_config(ROOT / "pipelines/learn.yaml").with_overrides({
        "tracking.enabled": False, "model_dir": None, "trainer.max_epochs": args.epochs,
        "data.train_windows_per_epoch": args.windows, "trainer.early_stop_patience": 0, "trainer.max_time_s": None,
        "data.split.seed": seed})
    first_seed = 100 + 10 * seed

    def measure(plan_or_grid, name: str, noise_seed: int) -> Path:
        raw = work / "raw" / name
        if isinstance(plan_or_grid, Path):
            generate_tunnel(raw, plan=plan_or_grid, seed=noise_seed)
        else:
            generate_tunnel(raw, grid=plan_or_grid, cycles=3, seed=noise_seed)
        out = work / "proc" / f"{name}.parquet"
        ingest_to_file(raw, out)
        shutil.rmtree(raw)
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
        rec, files = train_ensemble(cfg, members=args.members, first_seed=first_seed, split=split_for(paths, first))
        write_ensemble(work / name, files)
        return load_ensemble(work / name), rec, time.perf_counter() - t0

    p0 = measure(_initial_grid(), "initial", 1000 * seed)
    first = prepare_data(read_table([p0]), base_cfg.data).split
    init_minutes = sum(3 / g["frequency_hz"] + ranges.setup_s for g in _initial_grid()) * 4 / 60
    ens0, rec0, fit_s = fit([p0], "ens-initial", first)
    err0 = _region_error(ens0, region, truth)
    print(f"seed {seed} initial: {init_minutes:.1f} tunnel min, region nMSE {err0:.4f} (EF-legs region "
          f"{_region_error(ens0, ef_region, ef_truth):.4f}), test coverage "
          f"{rec0['calibration'].get('coverage_test_after')} ({fit_s:.0f} s)", flush=True)
    arms = {a: {"paths": [p0], "ens": ens0, "dir": "ens-initial", "minutes": [init_minutes], "error": [err0],
                "runs": [0]} for a in ARMS}
    rng = np.random.default_rng(1000 + seed)
    rand = _random_stream(ranges, rng)
    grid = iter(_grid_runs(ranges, np.random.default_rng(2000 + seed)))
    costs = {"plan_s": [], "fit_s": [fit_s]}
    for r in range(1, args.rounds + 1):
        t0 = time.perf_counter()
        (work / f"plan-{r}").mkdir()  # plan.md goes beside each manifest: one folder per round
        plan_path = work / f"plan-{r}" / "plan.toml"
        prec = plan_from_files(work / arms["planned"]["dir"], GAITS, args.runs, plan_path, settings=s,
                               campaign_id=f"planned-{r}", date="2026-01-01", region=region)
        costs["plan_s"].append(time.perf_counter() - t0)
        # random and grid runs are consumed in order: a round takes the next runs of its stream
        rand_runs = [next(rand) for _ in range(4 * args.runs)]
        recs = {"planned": (plan_path, prec),
                "random": (work / f"random-{r}.toml", None), "grid": (work / f"grid-{r}.toml", None)}
        rrec = _take(rand_runs, ranges, prec["tunnel_s"], recs["random"][0], f"random-{r}")
        rand = _chain(rand_runs[rrec["n_runs"]:], rand)
        grid_runs = [next(grid) for _ in range(4 * args.runs)]
        grec = _take(grid_runs, ranges, prec["tunnel_s"], recs["grid"][0], f"grid-{r}")
        grid = _chain(grid_runs[grec["n_runs"]:], grid)
        recs["random"], recs["grid"] = (recs["random"][0], rrec), (recs["grid"][0], grec)
        for arm in ARMS:
            path, rec = recs[arm]
            a = arms[arm]
            a["paths"].append(measure(path, f"{arm}-{r}", 1000 * seed + r))
            a["dir"] = f"ens-{arm}-{r}"
            a["ens"], _, fs = fit(a["paths"], a["dir"], first)
            costs["fit_s"].append(fs)
            a["minutes"].append(a["minutes"][-1] + rec["tunnel_s"] / 60)
            a["error"].append(_region_error(a["ens"], region, truth))
            a["runs"].append(a["runs"][-1] + rec["n_runs"])
            print(f"seed {seed} round {r} {arm}: +{rec['n_runs']} runs, {a['minutes'][-1]:.1f} tunnel min, "
                  f"region nMSE {a['error'][-1]:.4f} ({fs:.0f} s fit)", flush=True)
    return {"seed": seed, "initial_coverage_test": rec0["calibration"].get("coverage_test_after"),
            "arms": {k: {m: v[m] for m in ("minutes", "error", "runs")} for k, v in arms.items()},
            "costs": {**costs, "total_s": time.perf_counter() - t_start}}


def _chain(head, tail):
    yield from head
    yield from tail


def reach_minutes(minutes, error, target: float) -> float | None:
    """First tunnel minute at which the error curve (linear between rounds) is at or below ``target``."""
    for i in range(len(error)):
        if error[i] <= target:
            if i == 0:
                return float(minutes[0])
            m0, m1, e0, e1 = minutes[i - 1], minutes[i], error[i - 1], error[i]
            return float(m0 + (m1 - m0) * (e0 - target) / (e0 - e1))
    return None


def aggregate(seeds: list[dict]) -> dict:
    """Mean and spread over seeds; tunnel minutes (added to the initial campaign) to reach the other arms' final error."""
    out: dict = {"seeds": [s["seed"] for s in seeds], "arms": {}, "reach": {}}
    for arm in ARMS:
        m = np.array([s["arms"][arm]["minutes"] for s in seeds])
        e = np.array([s["arms"][arm]["error"] for s in seeds])
        out["arms"][arm] = {"minutes_mean": m.mean(0).tolist(), "error_mean": e.mean(0).tolist(),
                            "error_min": e.min(0).tolist(), "error_max": e.max(0).tolist(),
                            "error_sd": (e.std(0, ddof=1) if len(seeds) > 1 else 0 * e[0]).tolist()}
    for other in ("random", "grid"):
        ratios, added, notes = [], [], []
        for s in seeds:
            p, o = s["arms"]["planned"], s["arms"][other]
            m0 = p["minutes"][0]
            hit = reach_minutes(p["minutes"], p["error"], o["error"][-1])
            if hit is None:
                notes.append(f"seed {s['seed']}: planned never reached {other}'s final error {o['error'][-1]:.4f} "
                             f"(its final {p['error'][-1]:.4f})")
                continue
            added.append(hit - m0)
            ratios.append((hit - m0) / (o["minutes"][-1] - m0))
        out["reach"][other] = {
            "what": f"tunnel minutes beyond the initial campaign the planned arm needs to reach {other}'s final "
                    f"region error (linear between rounds), and that as a share of {other}'s minutes",
            "added_minutes": added, "share": ratios, "not_reached": notes,
            **({"share_mean": float(np.mean(ratios)), "share_min": float(np.min(ratios)),
                "share_max": float(np.max(ratios))} if ratios else {})}
    return out


def write_results(work: Path, out: Path, extra: dict) -> dict:
    seeds = [json.loads(p.read_text()) for p in sorted(work.glob("seed-*.json"))]
    if not seeds:
        raise SystemExit(f"no seed results in {work}")
    agg = aggregate(seeds)
    result = {"description": __doc__.splitlines()[0], **extra, **agg, "per_seed": seeds}
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_plan.json").write_text(json.dumps(result, indent=2) + "\n")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for arm, style in (("planned", "o-"), ("random", "s--"), ("grid", "^:")):
        a = agg["arms"][arm]
        line, = ax.plot(a["minutes_mean"], a["error_mean"], style, label=f"{arm} (mean of {len(seeds)} seeds)")
        ax.fill_between(a["minutes_mean"], a["error_min"], a["error_max"], color=line.get_color(), alpha=0.2)
    ax.set_xlabel("tunnel minutes (cycles / f + setup per run)")
    ax.set_ylabel("ensemble nMSE on the gaits' operating region")
    ax.set_yscale("log")
    ax.set_title("planned vs random vs grid runs (virtual tunnel; band: min-max over seeds)", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "bench_plan.png", dpi=100)
    plt.close(fig)
    return result


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--runs", type=int, default=8, help="planned runs per round")
    ap.add_argument("--members", type=int, default=3)
    ap.add_argument("--epochs", type=int, default=2)
    ap.add_argument("--windows", type=int, default=2500, help="training windows per epoch")
    ap.add_argument("--candidates", type=int, default=80, help="candidate runs of the planner")
    ap.add_argument("--work", type=Path, default=Path("/tmp/bench_plan"))
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    ap.add_argument("--aggregate-only", action="store_true", help="rewrite the results from WORK's seed files")
    args = ap.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    info_path = args.work / "setup.json"
    if args.aggregate_only:
        write_results(args.work, args.out, json.loads(info_path.read_text()))
        return 0

    from workbench.plan.planner import PlanSettings
    from workbench.project import load_params
    from workbench.virtual_lab.settings import TunnelSettings
    from workbench.virtual_lab.tunnel import truth_model

    t0 = time.perf_counter()
    settings = PlanSettings.from_dict(load_params(ROOT / "pipelines/plan.yaml", "plan"))
    region, ef_region, cmp = _regions(settings)
    tm = truth_model("rich", TunnelSettings().physics, [])
    truth, ef_truth = tm.wrench(region.motion), tm.wrench(ef_region.motion)
    print(f"regions ({time.perf_counter() - t0:.0f} s): {json.dumps(cmp)}", flush=True)
    extra = {"rounds": args.rounds, "runs_per_round": args.runs, "members": args.members, "epochs": args.epochs,
             "windows_per_epoch": args.windows, "candidates": args.candidates, "setup_s": settings.ranges.setup_s,
             "cycles": settings.ranges.cycles, "grid_flows_mps": list(GRID_FLOWS), "region": region.summary(),
             "region_legs": cmp}
    info_path.write_text(json.dumps(extra, indent=2) + "\n")
    for seed in args.seeds:
        res = run_seed(seed, args, settings, region, truth, ef_region, ef_truth)
        (args.work / f"seed-{seed}.json").write_text(json.dumps(res, indent=2) + "\n")
        result = write_results(args.work, args.out, extra)
        print(f"seed {seed} done in {res['costs']['total_s']:.0f} s; reach: {json.dumps(result['reach'])}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
