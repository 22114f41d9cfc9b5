"""Run the whole pipeline under a named parameter profile and time every stage (issue 14.7).

    python benchmarks/paper_scale.py                       # the paper's study (pipelines/profiles/paper.yaml)
    python benchmarks/paper_scale.py --dir /data/paper     # where the scratch copy goes (default: a temp folder)
    python benchmarks/paper_scale.py --print-set           # the profile as `dvc exp run` -S flags

What it does, so that the numbers mean one thing:
1. clones the CURRENT COMMIT of this repository into a scratch folder (`git clone --shared`: committed
   code only, nothing from this working tree's datasets or stores, its own MLflow/Optuna/DVC state);
2. writes the profile's values into the copy's pipelines/*.yaml (only study sizes: the tasks and the
   trials' protocol are the demo's);
3. runs `dvc repro` there with this interpreter's tools (the copy's own package first on PYTHONPATH),
   reading DVC's "Running stage" lines to time each stage;
4. writes the stage times, the total and the copy's headline results to
   benchmarks/results/<profile>.json and .md (this repository), and leaves the copy for inspection
   unless --clean.

A failed stage stops the run; the times measured so far and the failing stage are still written.
The scratch folder is refused when it exists and was not made by this script (a marker file).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
MARKER = ".workbench-profile-run"
STAGE_LINE = re.compile(r"Running stage '([^']+)'")


def load_profile(path: Path) -> dict:
    doc = yaml.safe_load(path.read_text())
    if not isinstance(doc, dict) or not isinstance(doc.get("set"), dict):
        raise SystemExit(f"{path}: a profile needs a 'set' mapping of '<file>:<dotted key>': value")
    for key in doc["set"]:
        if ":" not in key:
            raise SystemExit(f"{path}: key {key!r} is not '<params file>:<dotted key>'")
    return doc


def set_flags(profile: dict) -> list[str]:
    """The profile as `dvc exp run -S` arguments."""
    out = []
    for key, value in profile["set"].items():
        out += ["-S", f"{key}={json.dumps(value) if not isinstance(value, str) else value}"]
    return out


def apply_profile(copy: Path, profile: dict) -> list[str]:
    """Write the profile's values into the copy's params files; refuse keys the files do not have."""
    by_file: dict[str, list[tuple[str, object]]] = {}
    for key, value in profile["set"].items():
        file, _, dotted = key.partition(":")
        by_file.setdefault(file, []).append((dotted, value))
    changed = []
    for file, items in by_file.items():
        path = copy / file
        doc = yaml.safe_load(path.read_text())
        for dotted, value in items:
            node = doc
            parts = dotted.split(".")
            for part in parts[:-1]:
                if not isinstance(node, dict) or part not in node:
                    raise SystemExit(f"profile: {file} has no key {dotted!r} (at {part!r})")
                node = node[part]
            if not isinstance(node, dict) or parts[-1] not in node:
                raise SystemExit(f"profile: {file} has no key {dotted!r}")
            old = node[parts[-1]]
            node[parts[-1]] = value
            changed.append(f"{file}:{dotted}: {old!r} -> {value!r}")
        path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return changed


def make_copy(target: Path) -> Path:
    if target.exists():
        if not (target / MARKER).exists():
            raise SystemExit(f"{target} exists and was not made by {Path(__file__).name}; choose another --dir")
        shutil.rmtree(target)
    commit = subprocess.check_output(["git", "rev-parse", "HEAD"], cwd=ROOT, text=True).strip()
    subprocess.run(["git", "clone", "-q", "--shared", str(ROOT), str(target)], check=True)
    subprocess.run(["git", "checkout", "-q", commit], cwd=target, check=True)
    (target / MARKER).write_text(json.dumps({"source": str(ROOT), "commit": commit, "time": time.time()}))
    # keep the marker out of git status (and so out of DVC's view of the workspace)
    with open(target / ".git" / "info" / "exclude", "a") as f:
        f.write(f"\n{MARKER}\n")
    return target


def run_repro(copy: Path, log_path: Path) -> tuple[list[dict], int, float]:
    env = dict(os.environ)
    bin_dir = str(Path(sys.executable).parent)
    env["PATH"] = bin_dir + os.pathsep + env.get("PATH", "")
    env["PYTHONPATH"] = str(copy) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env.setdefault("MPLBACKEND", "Agg")
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    env.pop("MLFLOW_TRACKING_URI", None)
    stages: list[dict] = []
    t0 = time.monotonic()
    with open(log_path, "w") as log:
        proc = subprocess.Popen([str(Path(bin_dir) / "dvc"), "repro"], cwd=copy, env=env, text=True,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, bufsize=1)
        try:
            for line in proc.stdout:
                now = time.monotonic()
                log.write(line)
                log.flush()
                m = STAGE_LINE.search(line)
                if m:
                    if stages and "s" not in stages[-1]:
                        stages[-1]["s"] = round(now - stages[-1]["start"], 1)
                    stages.append({"stage": m.group(1), "start": now})
                    print(f"[{now - t0:7.0f} s] {m.group(1)}", flush=True)
            rc = proc.wait()
        except BaseException:
            proc.terminate()
            proc.wait()
            raise
    end = time.monotonic()
    if stages and "s" not in stages[-1]:
        stages[-1]["s"] = round(end - stages[-1]["start"], 1)
    for s in stages:
        s.pop("start")
    return stages, rc, round(end - t0, 1)


def group(stage: str) -> str:
    return stage.split("@", 1)[0]


def write_results(out: Path, result: dict) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(result, indent=2) + "\n")
    lines = [f"# Profile `{result['profile']}`: whole pipeline, time per stage", "",
             f"Commit {result['commit'][:10]}, {result['date']}, {result['machine']}, load average at start "
             f"{result['load_at_start']}. `dvc repro` {'succeeded' if result['rc'] == 0 else 'FAILED (rc %d)' % result['rc']}"
             f" in **{result['total_s']:.0f} s ({result['total_s'] / 60:.1f} min)**; target under 60 min.", "",
             "| stage | s |", "|---|---|"]
    lines += [f"| `{s['stage']}` | {s['s']:.0f} |" for s in result["stages"]]
    lines += ["", "Profile values:", ""] + [f"- {c}" for c in result["changed"]]
    if result.get("headline"):
        lines += ["", "Headline results of the run (datasets/reports/headline.json of the copy):", "", "```",
                  json.dumps(result["headline"], indent=2)[:4000], "```"]
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--profile", default=str(ROOT / "pipelines/profiles/paper.yaml"), help="profile YAML")
    p.add_argument("--dir", default=None, help="scratch copy (default: a new temp folder)")
    p.add_argument("--out", default=None, help="results (default: benchmarks/results/<profile>.json/.md)")
    p.add_argument("--print-set", action="store_true", help="print the profile as `dvc exp run` -S flags and stop")
    p.add_argument("--clean", action="store_true", help="remove the scratch copy afterwards")
    args = p.parse_args(argv)
    profile = load_profile(Path(args.profile))
    if args.print_set:
        print(" ".join(f"'{a}'" if " " in a else a for a in set_flags(profile)))
        return 0
    name = profile.get("name", Path(args.profile).stem)
    target = Path(args.dir) if args.dir else Path(tempfile.mkdtemp(prefix=f"workbench-{name}-")) / "project"
    copy = make_copy(target)
    changed = apply_profile(copy, profile)
    print(f"profile {name}: copy at {copy}", flush=True)
    for c in changed:
        print("  " + c)
    load = os.getloadavg()[0]
    stages, rc, total = run_repro(copy, copy / "profile-run.log")
    headline = None
    hp = copy / "datasets/reports/headline.json"
    if hp.exists():
        headline = json.loads(hp.read_text())
    result = {
        "profile": name, "commit": subprocess.check_output(["git", "rev-parse", "HEAD"], cwd=copy, text=True).strip(),
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "machine": f"{os.cpu_count()} cores, {platform.machine()}", "load_at_start": round(load, 2),
        "rc": rc, "total_s": total, "stages": stages, "changed": changed, "copy": str(copy),
        "by_group_s": {g: round(sum(s["s"] for s in stages if group(s["stage"]) == g), 1)
                       for g in dict.fromkeys(group(s["stage"]) for s in stages)},
        "headline": headline,
    }
    out = Path(args.out) if args.out else ROOT / "benchmarks/results" / name
    write_results(out, result)
    print(f"{'done' if rc == 0 else 'FAILED'}: {total:.0f} s; {out.with_suffix('.md')}")
    if args.clean and rc == 0:
        shutil.rmtree(copy.parent if not args.dir else copy)
    return rc


if __name__ == "__main__":
    sys.exit(main())
