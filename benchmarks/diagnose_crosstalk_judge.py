"""Issue 13: the crosstalk's held-out test at step 1, on the split and cross-fitted, for one campaign.

The selection judges ``loadcell_crosstalk`` with every parameter set held out once
(``selection.judge_folds``, section 3 of docs/diagnose.md). This script shows what that changes on
a campaign folder: the crosstalk candidate of step 1 (entries pruned on the training runs, judged
beside the other channels' residuals against those residuals alone) tested on the split's
held-out sets only and cross-fitted, with the split's held-out sets as one fold and the training
sets dealt to the others in a few random draws (the workbench deals them by hash), and the gain
per parameter set:

    .venv/bin/python benchmarks/diagnose_crosstalk_judge.py build/bench/s11-plants/copy-xt_fz_fy_5pc \\
        --model datasets/models/fed-lstm
    .venv/bin/python benchmarks/diagnose_crosstalk_judge.py build/bench/demo-plants/copy-clean --model ef

Measured 29 Nov 2026 (docs/diagnose.md, section 7, "The crosstalk judged cross-fitted"): FED-LSTM,
the re-measured demo copy with 5 % fz-from-fy planted, split t 2.4, cross-fitted 10.0-11.9; its
clean copy -1.4 to -4.7; the battery's 12-set campaign with 3 % planted 1.6-2.9, clean 0.5-2.0.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("campaign", help="a campaign folder (contract v1 raw files)")
    ap.add_argument("--model", default="ef", help="ef or a trained model folder (default ef)")
    ap.add_argument("--folds", type=int, default=3, help="folds, the split's held-out sets one of them (default 3)")
    ap.add_argument("--draws", type=int, default=5, help="random deals of the training sets to the folds (default 5)")
    ap.add_argument("--params", default=str(ROOT / "pipelines" / "diagnose.yaml"), help="the diagnose settings")
    args = ap.parse_args()

    import numpy as np

    from workbench.diagnose.chain import Active, Configuration, Lowpass
    from workbench.diagnose.data import parameter_key, prepare
    from workbench.diagnose.library import default_library
    from workbench.diagnose.loop import DiagnoseSettings
    from workbench.diagnose.loop_threads import _chunks_for
    from workbench.diagnose.problem import Problem
    from workbench.diagnose.selection_candidates import _linear_candidates, prune
    from workbench.diagnose.selection_claims import _judged, assess
    from workbench.diagnose.selection_judge import crossfit_judge, crossfit_sse
    from workbench.hydro.legmodel import load_leg_model
    from workbench.ingest import ingest_campaign
    from workbench.params import read_section

    s = DiagnoseSettings.from_mapping(*read_section(args.params, "diagnose"))
    model = load_leg_model(args.model)
    frame = ingest_campaign(Path(args.campaign), params={"workers": 1}).frame
    camp = prepare(frame, _chunks_for(model, s.data))
    problem = Problem(camp, model, Lowpass(6.0, 4), s.fit)
    base = problem.fit(Configuration(), names=[])
    lib = default_library(None, s.library.link_x_m, s.library.link_quadrature, 0.7, options=s.library.options)
    xt = next(e for e in lib if e.name == "loadcell_crosstalk")
    split = dataclasses.replace(s.selection, judge_folds=0)
    c = prune(split, problem, _linear_candidates(split, problem, Configuration(), base.coefs(), [], [xt])[0],
              base.coefs())
    assess(split, problem, c, base.coefs(), base, Configuration(), 1.0, None)
    entries = {k.split(".", 1)[1]: round(v, 4) for k, v in c.fit.coefs().items() if k in c.names}
    print(f"{Path(args.campaign).name}, {args.model}: entries {entries}")
    print(f"  split: t {c.test['t']:.2f}, p {c.test['p']:.2g} over {c.test['n_blocks']} held-out blocks")

    j = _judged(problem, c, base.coefs())
    null = problem.fit(j.config.with_effect(Active(j.effect, j.effect.null_variants(j.active.nl)[0])), base.coefs(),
                       j.names)
    keys = [parameter_key(dict(r.params), s.data.split_decimals) for r in camp.runs]
    sets = sorted(set(keys))
    set_of_run = np.array([sets.index(k) for k in keys])
    held_set = np.zeros(len(sets), bool)
    held_set[set_of_run[camp.heldout]] = True
    rng = np.random.default_rng(0)
    gr = j.fit.grams
    for draw in range(args.draws):
        train = rng.permutation(np.flatnonzero(~held_set))
        fold_of_set = np.zeros(len(sets), int)
        fold_of_set[train] = 1 + np.arange(len(train)) % max(args.folds - 1, 1)
        fold = fold_of_set[set_of_run[gr.run]]
        test, _ = crossfit_judge(null, j.fit, fold, problem.weights, problem.settings.hac_lags)
        print(f"  cross-fitted, draw {draw}: t {test['t']:.2f}, p {test['p']:.2g} over {test['n_blocks']} blocks")
    # the gain per set of the last draw: how much the misfit scatters it
    sse_a = crossfit_sse(j.fit, fold, problem.weights, problem.settings.hac_lags)
    sse_b = crossfit_sse(null, fold, problem.weights, problem.settings.hac_lags)
    llr = (0.5 * gr.n[:, None] * np.log(np.maximum(sse_b, 1e-300) / np.maximum(sse_a, 1e-300))).sum(axis=1)
    per_set = np.array([llr[set_of_run[gr.run] == i].sum() for i in range(len(sets))])
    print(f"  gain per set (last draw): mean {per_set.mean():.1f}, sd {per_set.std(ddof=1):.1f}, "
          f"set-level t {per_set.mean() / per_set.std(ddof=1) * np.sqrt(len(sets)):.2f} over {len(sets)} sets")
    return 0


if __name__ == "__main__":
    sys.exit(main())
