"""``workbench plan-campaign``: propose the next tunnel campaign (contract section 6)."""

from __future__ import annotations

from pathlib import Path

from workbench.commands._help import add_verb

EXAMPLES = """\
  # 12 runs that most reduce the FED-LSTM ensemble's uncertainty where the retained gaits swim,
  # plus the runs the diagnosis asks for; writes the manifest and plan.md beside it
  workbench plan-campaign --model datasets/models/fed-lstm-ensemble \\
      --gaits datasets/gaits/straight-lstm.json datasets/gaits/turn-lstm.json \\
      --diagnosis datasets/diagnosis/demo-tunnel-ef --n-runs 12 --out datasets/plans/next-campaign.toml

  # measure it in the virtual tunnel (or hand the manifest to the rig's controller), then add it
  workbench virtual-lab tunnel datasets/raw/next-campaign --plan datasets/plans/next-campaign.toml
  workbench campaign add datasets/raw/next-campaign

  # cheaper runs: 3 cycles each, a longer setup per run, only the best gait of each file
  workbench plan-campaign --model ENS --gaits datasets/gaits/*-lstm.json --n-runs 8 --out /tmp/p.toml \\
      --set ranges.cycles=3 --set ranges.setup_s=120 --set max_rank=1
"""


def register(sub) -> None:
    """Add the ``plan-campaign`` verb."""
    from pathlib import Path

    p = add_verb(sub, "plan-campaign", help="propose the next tunnel campaign (runs that teach the models most)",
                 description="Propose N tunnel runs (motion parameters within the rig's ranges, flow speed, cycles) "
                             "that most reduce the FED-LSTM ensemble's uncertainty at the states the retained gaits "
                             "put the legs in (the operating region, from full-body swims of the gaits): greedy "
                             "integrated posterior variance over the ensemble, per second of tunnel time. With "
                             "--diagnosis, runs that separate effects the diagnosis calls ambiguous come first. "
                             "Writes a contract-v1 campaign.toml whose runs have no files yet (they are to be "
                             "measured) and plan.md beside it: why each run, its expected gain, the tunnel time. "
                             "See docs/campaigns.md.",
                 examples=EXAMPLES)
    p.add_argument("--model", required=True, type=Path, metavar="ENSEMBLE_DIR",
                   help="ensemble folder written by `workbench train-ensemble` (ensemble.json + members)")
    p.add_argument("--gaits", required=True, nargs="+", type=Path, metavar="GAIT_FILE",
                   help="retained gaits, datasets/gaits/<task>-<model>.json (contract section 5)")
    p.add_argument("--n-runs", required=True, type=int, metavar="N", help="runs to propose (besides the diagnosis's)")
    p.add_argument("--out", required=True, type=Path, metavar="PLAN.toml", help="the manifest to write; plan.md "
                                                                               "goes beside it")
    p.add_argument("--diagnosis", type=Path, metavar="DIR", help="a `workbench diagnose` folder (or diagnosis.json): "
                   "effects flagged ambiguous_with get runs that tell them apart")
    p.add_argument("--params", type=Path, default=None,
                   help="YAML with a 'plan' section (default: pipelines/plan.yaml; built-in defaults "
                        "where it is absent)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a key of the plan section, e.g. --set ranges.cycles=3 (repeatable)")
    p.add_argument("--id", help="campaign id of the plan (default: from the --out file name)")
    p.add_argument("--date", help="date of the manifest, YYYY-MM-DD (default: today)")
    p.add_argument("--robot", type=Path, default=Path("pipelines/robot.yaml"), help="robot constants for the swims")
    p.add_argument("--drag", type=Path, help="drag.json of the body (workbench fit-drag) for the swims")
    p.add_argument("--ef-legs", action="store_true",
                   help="swim every gait file's gaits with EF legs (default: with the model each file's gaits were "
                        "optimised with, tabulated as the optimiser does; EF where that model is not available)")
    p.set_defaults(func=run)


def own_legs(root: str | Path | None = None, fallback_note: list | None = None):
    """``legs`` for :func:`workbench.plan.region.operating_region`: each gait file swum with its own model.

    The model is the gait file's ``model_spec`` (else ``model_source.model_path``, else ``model``),
    a path taken as is or under ``root``; a window net without a flow provider of its own (the
    FED-LSTM) is tabulated with the file's ``settings.tabulation``, as the optimiser swam it
    (:class:`workbench.gait.tabulate.TabulatedLegModel`). A model that cannot be loaded falls back
    to EF legs, with the reason in the note (and the region's ``leg_models``).
    """
    from pathlib import Path

    from workbench.errors import WorkbenchError
    from workbench.gait.tabulate import TabulatedLegModel, TabulationSettings
    from workbench.hydro.legmodel import load_leg_model
    from workbench.hydro.simulator import DEFAULT_DT_S

    cache: dict = {}

    def legs(path, doc: dict, gaits):
        spec = doc.get("model_spec") or (doc.get("model_source") or {}).get("model_path") or doc.get("model")
        if not spec:
            return None, "EF (the gait file names no model)"
        spec = str(spec)
        cand = Path(spec)
        if not cand.exists() and root is not None and (Path(root) / spec).exists():
            spec = str(Path(root) / spec)
        try:
            model = cache[spec] if spec in cache else cache.setdefault(spec, load_leg_model(spec))
        except (WorkbenchError, OSError, ValueError) as exc:
            return None, f"EF (fallback: the gait file's model {doc.get('model_spec') or spec!r} is not available: " \
                         f"{str(exc).splitlines()[0][:160]})"
        if callable(getattr(model, "flow_provider", None)) or int(getattr(model, "seq_len", 0) or 0) <= 1:
            return model, f"{getattr(model, 'name', spec)} ({spec})"
        tab = TabulationSettings.from_dict(((doc.get("settings") or {}).get("tabulation")))
        return (TabulatedLegModel(model, gaits, tab, sim_dt_s=DEFAULT_DT_S),
                f"{getattr(model, 'name', spec)} ({spec}), tabulated as the optimiser does")

    return legs


def _settings(args):
    """The ``plan`` section of --params (built-in defaults where the default file is absent), --set on top."""
    import yaml

    from workbench.errors import ParamsError
    from workbench.params import read_section, set_dotted
    from workbench.plan.planner import PlanSettings

    doc, source = read_section(args.params, "plan", default="pipelines/plan.yaml")
    for item in args.set:
        key, sep, value = item.partition("=")
        if not sep:
            raise ParamsError(f"--set {item!r} is not key=value", where="plan", hint="e.g. --set ranges.cycles=3")
        set_dotted(doc, key, yaml.safe_load(value), section="plan", path=source)
    return PlanSettings.from_dict(doc, path=source)


def read_gait_files(paths, max_rank: int | None = None) -> list:
    """The gait files (contract section 5) read and checked: :func:`workbench.plan.region.gait_files_from_docs`."""
    import json

    from workbench.errors import ContractError
    from workbench.plan.region import gait_files_from_docs

    docs = []
    for p in map(Path, paths):
        try:
            docs.append((p, json.loads(p.read_text(encoding="utf-8"))))
        except FileNotFoundError:
            raise ContractError("gait file not found", path=p) from None
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ContractError(f"not a gait file ({type(exc).__name__}: {exc}); expected "
                                "{'solutions': [{'rank', 'params'}, ...]}", path=p) from None
    return gait_files_from_docs(docs, max_rank)


def read_diagnosis(path) -> dict:
    """``diagnosis.json`` from a file or the folder holding it (contract section 4)."""
    from workbench.contract.jsonfile import read_json
    from workbench.plan.diagnosis_runs import check_diagnosis

    p = Path(path)
    p = p / "diagnosis.json" if p.is_dir() else p
    return check_diagnosis(read_json(p, "diagnosis.json", hint="pass the folder workbench diagnose wrote"), p)


def write_plan(out, texts: dict[str, str]) -> None:
    """The manifest and plan.md beside it, as one set (both new or both old after a kill).

    An existing file of either name that an earlier plan-campaign did not write is refused, never replaced.
    """
    from workbench import atomic

    out = Path(out)
    with atomic.atomic_files(out.parent, list(texts), "plan-campaign", set_name=f"plan-campaign-{out.stem}") as tmp:
        for name, text in texts.items():
            tmp[name].write_text(text, encoding="utf-8")


def plan_from_files(model_dir, gait_paths, n_runs: int, out, *, diagnosis=None, settings=None,
                    campaign_id: str | None = None, date: str | None = None, robot_yaml="pipelines/robot.yaml",
                    drag_json=None, legs=None, region=None, write: bool = True) -> dict:
    """Read the inputs, plan (:func:`workbench.plan.planner.plan_campaign`), write ``out`` and plan.md; the record.

    Bad gait files are refused before the ensemble is loaded; ``region``: an operating region
    already swum from these gait files (the robot file is then not read).
    """
    from workbench.hydro.robot import load_robot
    from workbench.learn.ensemble import load_ensemble
    from workbench.plan.planner import PlanSettings, plan_campaign, plan_texts

    s = settings or PlanSettings()
    files = read_gait_files(gait_paths, s.max_rank)
    ensemble = load_ensemble(model_dir)
    doc = read_diagnosis(diagnosis) if diagnosis is not None else None
    robot = load_robot(robot_yaml, drag_json=drag_json) if region is None else None
    record = plan_campaign(ensemble, files, n_runs, out, diagnosis=doc, settings=s, campaign_id=campaign_id,
                           robot=robot, ensemble_dir=model_dir, region=region, legs=legs)
    if write:
        write_plan(out, plan_texts(out, record, s, date))
    return record


def run(args) -> int:
    """Plan and report."""
    from workbench.console import info

    rec = plan_from_files(args.model, args.gaits, args.n_runs, args.out, diagnosis=args.diagnosis,
                          settings=_settings(args), campaign_id=args.id, date=args.date, robot_yaml=args.robot,
                          drag_json=args.drag, legs=None if args.ef_legs else own_legs())
    drop = 100 * (1 - rec["total_after"] / max(rec["total_before"], 1e-30))
    info(f"planned {rec['n_runs']} runs ({rec['n_diagnosis_runs']} for the diagnosis), "
         f"{rec['tunnel_s'] / 60:.1f} tunnel minutes; region-weighted variance {drop:.0f} % lower expected")
    info(f"wrote {args.out} (files pending) and {args.out.with_name('plan.md')} in {rec['cost_s']['total']:.0f} s")
    return 0
