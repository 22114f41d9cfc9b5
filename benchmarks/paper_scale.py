"""Run the whole pipeline under a named parameter profile and time every stage (issue 14.7).

    python benchmarks/paper_scale.py                       # the paper's study (pipelines/profiles/paper.yaml)
    python benchmarks/paper_scale.py --dir /data/paper     # where the scratch copy goes (default: a temp folder)
    python benchmarks/paper_scale.py --print-set           # the profile as `dvc exp run` -S flags

What it does, so that the numbers mean one thing:
1. clones the CURRENT COMMIT of this repository into a scratch folder (`git clone --shared`: committed
   code only, nothing from this working tree's datasets or stores, its own MLflow/Optuna/DVC state);
2. writes the profile's values into the copy's pipelines/*.yaml (only study sizes: the tasks and the
   trials' protocol are the demo's);
3. runs the pipeline there stage by stage (`dvc repro -s STAGE` in DVC's order) with this
   interpreter's tools (the copy's own package first on PYTHONPATH), timing each stage's wall and
   CPU time;
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
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
MARKER = ".workbench-profile-run"


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


def drop_stages(copy: Path, names: list[str]) -> list[str]:
    """Remove whole stages from the copy's dvc.yaml, and every other stage's deps on their outputs."""
    if not names:
        return []
    path = copy / "dvc.yaml"
    doc = yaml.safe_load(path.read_text())
    stages = doc["stages"]
    gone: list[str] = []
    for name in names:
        if name not in stages:
            raise SystemExit(f"profile: dvc.yaml has no stage {name!r} to drop")
        st = stages.pop(name)
        items = st.get("foreach") or [None]
        body = st.get("do", st)
        for out in body.get("outs", []) or []:
            out = out if isinstance(out, str) else next(iter(out))
            gone += [out.replace("${item}", str(i)) if i is not None else out for i in items]
    for st in stages.values():
        body = st.get("do", st)
        # an option whose value names a dropped output goes too (evaluate's --also lstm16=<folder>)
        tokens = str(body["cmd"]).split()
        keep = []
        for tok in tokens:
            if any(g in tok for g in gone) and keep and keep[-1].startswith("--"):
                keep.pop()
                continue
            keep.append(tok)
        body["cmd"] = " ".join(keep)
        if body.get("deps"):
            body["deps"] = [d for d in body["deps"] if (d if isinstance(d, str) else next(iter(d))) not in gone]
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return [f"dvc.yaml: stage {n} dropped" for n in names]


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


def stage_order(copy: Path, env: dict) -> list[str]:
    """The pipeline's stages, upstream first (DVC's own graph)."""
    code = ("import networkx as nx; from dvc.repo import Repo; g = Repo('.').index.graph; "
            "print('\\n'.join(s.addressing for s in reversed(list(nx.topological_sort(g)))))")
    out = subprocess.run([sys.executable, "-c", code], cwd=copy, env=env, check=True, capture_output=True, text=True)
    return [line for line in out.stdout.splitlines() if line.strip()]


def run_repro(copy: Path, log_path: Path) -> tuple[list[dict], int, float]:
    """`dvc repro -s STAGE` for every stage in DVC's order: wall time and CPU time (the stage's
    processes, user + system) per stage. CPU time barely depends on what else runs on the machine;
    wall time does (the load average at the start of each stage is recorded beside it)."""
    import resource

    env = dict(os.environ)
    bin_dir = str(Path(sys.executable).parent)
    env["PATH"] = bin_dir + os.pathsep + env.get("PATH", "")
    env["PYTHONPATH"] = str(copy) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env.setdefault("MPLBACKEND", "Agg")
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    env.pop("MLFLOW_TRACKING_URI", None)
    stages: list[dict] = []
    t0 = time.monotonic()
    rc = 0
    with open(log_path, "w") as log:
        for name in stage_order(copy, env):
            load = round(os.getloadavg()[0], 2)
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            start = time.monotonic()
            print(f"[{start - t0:7.0f} s] {name} (load {load})", flush=True)
            log.write(f"=== {name}\n")
            log.flush()
            proc = subprocess.Popen([str(Path(bin_dir) / "dvc"), "repro", "-s", name], cwd=copy, env=env,
                                    stdout=log, stderr=subprocess.STDOUT)
            try:
                rc = proc.wait()
            except BaseException:
                proc.terminate()
                proc.wait()
                raise
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
            stages.append({"stage": name, "s": round(time.monotonic() - start, 1), "cpu_s": round(cpu, 1),
                           "load_at_start": load})
            if rc != 0:
                stages[-1]["failed"] = True
                break
    return stages, rc, round(time.monotonic() - t0, 1)


def group(stage: str) -> str:
    return stage.split("@", 1)[0]


def write_results(out: Path, result: dict) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(result, indent=2) + "\n")
    lines = [f"# Profile `{result['profile']}`: whole pipeline, time per stage", "",
             f"Commit {result['commit'][:10]}, {result['date']}, {result['machine']}, load average at start "
             f"{result['load_at_start']}. `dvc repro` {'succeeded' if result['rc'] == 0 else 'FAILED (rc %d)' % result['rc']}"
             f" in **{result['total_s']:.0f} s ({result['total_s'] / 60:.1f} min)**; target under 60 min.", "",
             "Wall time depends on what else ran (load average at each stage's start); CPU time (the stage's "
             "processes, user + system) does not much: on an idle 2-core machine a stage's wall time lies "
             "between CPU/2 (both cores busy) and CPU (one).", "",
             "| stage | wall (s) | CPU (s) | load at start |", "|---|---|---|---|"]
    lines += [f"| `{s['stage']}` | {s['s']:.0f} | {s['cpu_s']:.0f} | {s['load_at_start']} |" for s in result["stages"]]
    cpu = sum(s["cpu_s"] for s in result["stages"])
    lines += [f"| **total** | **{result['total_s']:.0f}** | **{cpu:.0f}** | |"]
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
    changed = apply_profile(copy, profile) + drop_stages(copy, list(profile.get("drop_stages") or []))
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
