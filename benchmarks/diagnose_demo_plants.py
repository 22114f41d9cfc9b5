"""Issue 13 as an outside program runs it: plant effects into copies of the demo campaign, run the command.

The independent check the issue reports planted effects into copies of the demo tunnel campaign
(datasets/raw/demo-tunnel, 48 sets x 4 flow speeds, 192 runs, rich virtual truth) and ran
``workbench diagnose --campaign COPY --model ef``. This script does the same with the tests'
own planting formulas (``tests/diagnose/planting.py``, the battery's cases plus two the battery
does not have), through the real command line, and scores each diagnosis against the plant and
against the clean copy's claims (an effect claimed beside the plant that the clean copy does not
claim is an extra claim):

    .venv/bin/python benchmarks/diagnose_demo_plants.py                       # EF, every case
    .venv/bin/python benchmarks/diagnose_demo_plants.py --cases clean,xt_fz_fy_5pc --max-runs 0
    .venv/bin/python benchmarks/diagnose_demo_plants.py --model datasets/models/fed-lstm
    .venv/bin/python benchmarks/diagnose_demo_plants.py --params my-diagnose.yaml      # other settings

Copies and outputs go under build/bench/demo-plants (gitignored); a copy is planted once and reused.
Two to eight minutes a case on two cores (192 runs are ingested each time). Measured 29 Nov 2026
(docs/diagnose.md, section 7, "The demo campaign as an outside program plants it").
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "diagnose"))

DEFAULT_CASES = ("clean,servo_dead_60ms,servo_cmd_10ms_dead_40ms_lag,xt_fz_fy_5pc,crosstalk_tx_from_fz_2pc,"
                 "drift_fz_1.5mN_per_s,static_hip_torque,flow_tone_2Hz_5pc,vibration_3.3Hz,mount_mode_4.5Hz")


def _cases():
    import battery as B
    import planting as P

    extra = {
        "clean": B.Case("clean", lambda: [], {}),
        # the issue's own measurement: a 5 % crosstalk between two force channels
        "xt_fz_fy_5pc": B.Case("xt_fz_fy_5pc", lambda: [P.crosstalk("fz_n", "fy_n", 0.05)],
                               {"loadcell_crosstalk": {"x_fz_fy": 0.05}}),
    }
    known = [*extra, *(c.name for c in B.SINGLES + B.COMMAND_SERVOS + B.TONE_RANGE + B.PROBE)]

    def lookup(name: str):
        if name in extra:
            return extra[name]
        unknown = [n for n in name.split("+") if n not in known]
        if unknown:
            raise SystemExit(f"--cases: no case {unknown[0]!r}; known: {', '.join(known)} (or two joined by '+')")
        return B.pair(*name.split("+")) if "+" in name else B.case(name)

    return lookup


def _score(case, doc: dict, clean: dict | None) -> dict:
    claimed = {e["name"]: e.get("params", {}) for e in doc["effects"]}
    named, errors = [], {}
    for eff, params in case.expected.items():
        family = case.family.get(eff, (eff,))
        hit = next((f for f in family if f in claimed), None)
        named.append(f"{eff}->{hit or 'MISSED'}")
        for k, v in params.items():
            got = claimed.get(eff, {}).get(k)
            if got is not None:
                errors[f"{eff}.{k}"] = round(abs(got - v) / abs(v), 3)
    allowed = {f for eff in case.expected for f in case.family.get(eff, (eff,))}
    base = set() if clean is None else {e["name"] for e in clean["effects"]}
    extra = sorted(n for n in claimed if n not in allowed and n not in base)
    lines = [f"{u.get('frequency_hz'):.3f} Hz {','.join(u['channels'])}" for u in doc["unexplained"]
             if u.get("frequency_hz")]
    return {"named": named, "errors": errors, "extra": extra, "lines": lines,
            "params": {n: claimed[n] for n in case.expected if n in claimed}}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="ef", help="the --model of every diagnosis (default ef)")
    ap.add_argument("--cases", default=DEFAULT_CASES, help="comma-separated case names; 'clean' is the unplanted copy")
    ap.add_argument("--campaign", default=str(ROOT / "datasets" / "raw" / "demo-tunnel"), help="the campaign copied")
    ap.add_argument("--max-runs", type=int, help="passed on to the command (default: the project's pipeline file)")
    ap.add_argument("--params", metavar="YAML", help="passed on to the command: a parameter file with a 'diagnose' "
                    "section (default: the project's pipelines/diagnose.yaml); outputs are tagged with its name")
    ap.add_argument("--root", default=str(ROOT / "build" / "bench" / "demo-plants"))
    ap.add_argument("--json", metavar="FILE", help="also write every result as JSON")
    args = ap.parse_args()

    import planting as P

    lookup, root = _cases(), Path(args.root)
    root.mkdir(parents=True, exist_ok=True)
    tag = "all" if args.max_runs == 0 else str(args.max_runs or "default")
    if args.params:
        tag += "-" + Path(args.params).stem
    results, clean = {}, None
    for name in args.cases.split(","):
        case = lookup(name)
        folder = root / ("copy-" + name.lower().replace(".", "-").replace("+", "--"))
        if not (folder / "campaign.toml").exists():
            P.copy_campaign(Path(args.campaign), folder, case.plants())
        out = root / f"out-{Path(args.model).name}-{tag}-{folder.name[5:]}"
        cmd = [str(Path(sys.executable).parent / "workbench"), "diagnose", "--campaign", str(folder),
               "--model", args.model, "--out", str(out), "--no-mlflow"]
        if args.max_runs is not None:
            cmd += ["--max-runs", str(args.max_runs)]
        if args.params:
            cmd += ["--params", str(Path(args.params).resolve())]
        t0 = time.time()
        proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
        if proc.returncode:
            print(f"{name}: the command failed ({proc.returncode}): {proc.stderr.strip().splitlines()[-1:]}")
            continue
        doc = json.loads((out / "diagnosis.json").read_text())
        if name == "clean":
            clean = doc
        r = {**_score(case, doc, clean), "s": round(time.time() - t0)}
        results[name] = r
        print(f"{name}: named {r['named']} errors {r['errors']} extra {r['extra']} lines {r['lines']} "
              f"params {r['params']} {r['s']} s", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
