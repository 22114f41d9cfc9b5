"""Issue 13's planted-effect battery: the confusion table (planted against named), parameter errors, error removed.

Plants rig effects into copies of a rich-truth virtual tunnel campaign by editing its raw CSV
files with formulas of the tests' own (``tests/diagnose/planting.py``), ingests each copy and
diagnoses it; scores with ``tests/diagnose/battery.py``.

    .venv/bin/python benchmarks/diagnose_battery.py                        # EF, with and without --reference
    .venv/bin/python benchmarks/diagnose_battery.py --model lstm --mode ref # the trained FED-LSTM as base
    .venv/bin/python benchmarks/diagnose_battery.py --cases servo_dead_60ms,vibration_3.3Hz --sets 8
    .venv/bin/python benchmarks/diagnose_battery.py --mode noref --cases probe   # effects the battery does not plant
    .venv/bin/python benchmarks/diagnose_battery.py --mode noref --cases probe2  # the ends of issue 13's ranges
    .venv/bin/python benchmarks/diagnose_battery.py --mode noref --cases probe3  # pairs that trade off
    .venv/bin/python benchmarks/diagnose_battery.py --mode noref --cases probe4  # pairs of the issue's rig effects

Campaigns are cached under build/bench/diagnose (gitignored). Not part of ``make bench`` (about a
minute per case and base on an idle two-core machine).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "diagnose"))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="ef", help="base model(s), comma-separated: ef, lstm, ... (default ef)")
    ap.add_argument("--mode", default="both", choices=["ref", "noref", "both"],
                    help="with --reference (a clean campaign of the same rig), without, or both")
    ap.add_argument("--cases", help="comma-separated case names, or 'probe', 'probe2', 'probe3', 'probe4' (default: the battery's)")
    ap.add_argument("--sets", type=int, default=12,
                    help="parameter sets per campaign (x3 flow speeds; 1-64, the first 12 are the CI tests')")
    ap.add_argument("--root", default=str(ROOT / "build" / "bench" / "diagnose"))
    ap.add_argument("--json", metavar="FILE", help="also write every result as JSON")
    ap.add_argument("--data", metavar="KEY=VALUE", action="append", default=[],
                    help="a diagnose data setting for every diagnosis, e.g. split_cover=frequency_hz (repeatable)")
    args = ap.parse_args()

    import battery as B

    B.grid(args.sets)  # refuses an impossible --sets in one line before any campaign is written
    root = Path(args.root)
    root.mkdir(parents=True, exist_ok=True)
    from workbench.diagnose.data import DataSettings

    data, defaults = {}, DataSettings()
    for kv in args.data:
        key, _, value = kv.partition("=")
        if not hasattr(defaults, key):
            ap.error(f"--data {kv}: no data setting {key!r}; known: {', '.join(vars(defaults))}")
        data[key] = type(getattr(defaults, key))(value)
    bench = B.Bench(root, n_sets=args.sets, data=data)
    modes = {"ref": [True], "noref": [False], "both": [True, False]}[args.mode]
    out = {}
    for model in args.model.split(","):
        for with_ref in modes:
            cases = B.all_cases(with_ref)
            if args.cases in ("probe", "probe2", "probe3", "probe4"):  # the generalisation probes (battery.PROBE*)
                cases = {"probe": B.PROBE, "probe2": B.PROBE2, "probe3": B.probe3(), "probe4": B.probe4()}[args.cases]
                cases = list(cases)
            elif args.cases:  # in the order given (pairs as a+b)
                by_name = {c.name: c for c in B.all_cases(False) + B.PROBE + B.PROBE2 + B.probe3() + B.probe4()}
                unknown = [n for n in args.cases.split(",") if n not in by_name]
                if unknown:
                    ap.error(f"unknown case(s) {', '.join(unknown)}; known: {', '.join(by_name)}")
                cases = [by_name[n] for n in args.cases.split(",")]
            clean = bench.clean(model, with_ref)
            print(f"clean campaign, {model} {'with' if with_ref else 'without'} reference: claims "
                  f"{[e.name for e in clean.effects] or 'nothing'}", flush=True)
            results = []
            title = f"{model}, {'with --reference' if with_ref else 'no reference'}"
            out[title] = {"clean_claims": [e.name for e in clean.effects], "results": results}
            for c in cases:
                r = bench.run(c, model, with_ref)
                share = "-" if r["removed_share"] is None else f"{r['removed_share']:.0%}"
                print(f"  {c.name}: named {r['named']}, extra {r['extra']}, params {r['params']}, "
                      f"errors {({k: None if v is None else round(v, 3) for k, v in r['param_err'].items()})}, "
                      f"removed {share}, {r['seconds']:.0f} s", flush=True)
                results.append(r)
                if args.json:  # after every case: a long battery stopped early keeps what it measured
                    Path(args.json).write_text(json.dumps(out, indent=1, default=str))
            print(B.table(results, title), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
