"""``workbench evaluate``: EF vs the registered FED-LSTM on the held-out test parameter sets."""

from __future__ import annotations

from workbench.commands._help import add_verb

EXAMPLES = """\
  # the demo stage: metrics (contract section 5) and the paper's figures
  workbench evaluate --data datasets/processed/demo-tunnel.parquet \\
      --split datasets/models/fed-lstm/split.json \\
      --out datasets/metrics/leg_models.json --figures datasets/reports/leg_models

  # another model than the champion: a registry alias, a version, or a model folder
  workbench evaluate --data d.parquet --split s.json --out m.json --model models:/fed-lstm@tuned
  workbench evaluate --data d.parquet --split s.json --out m.json --model datasets/models/fed-lstm

  # add more models to the comparison (any load_leg_model spec)
  workbench evaluate --data d.parquet --split s.json --out m.json --also gru=models:/fed-lstm/4
"""


def register(sub) -> None:
    """Add the ``evaluate`` verb."""
    p = add_verb(sub, "evaluate", help="score EF and the FED-LSTM on held-out parameter sets (metrics, figures)",
                 description="Run the EF and the learned model through the leg force model interface on the "
                             "measured runs of the test parameter sets named by the split file that training "
                             "wrote, and write MSE and R^2 per channel, per flow speed and per parameter set to a "
                             "JSON metrics file (contract section 5). With --figures, also the paper's prediction "
                             "curves (Fig. 4) and the MSE box plot by flow speed (Fig. 5) as PNG. Logged to MLflow.",
                 examples=EXAMPLES)
    p.add_argument("--data", nargs="+", required=True, metavar="PARQUET",
                   help="processed tunnel Parquet file(s) or folder(s) of them; interpolated rows are ignored")
    p.add_argument("--split", required=True, help="split.json written by workbench train (model folder)")
    p.add_argument("--out", required=True, help="metrics JSON to write, e.g. datasets/metrics/leg_models.json")
    p.add_argument("--figures", metavar="DIR", help="write the PNG figures here")
    p.add_argument("--model", help="learned model: lstm (registry champion), models:/NAME@ALIAS, models:/NAME/V "
                                   "or a model folder (default: the file's evaluate.model)")
    p.add_argument("--also", action="append", default=[], metavar="NAME=SPEC", help="another model to score")
    p.add_argument("--config", default="pipelines/learn.yaml", help="learning parameter file (default: %(default)s)")
    p.add_argument("--tracking-uri", help="MLflow tracking URI (default: MLFLOW_TRACKING_URI, else the project's)")
    p.add_argument("--no-mlflow", action="store_true", help="do not log the evaluation to MLflow")
    p.add_argument("--dvc-stage", help="dvc_stage tag of the MLflow run (default: DVC_STAGE, else 'manual')")
    p.set_defaults(func=run)


def run(args) -> int:
    """Evaluate, write the metrics file and figures, log them."""
    from workbench.console import info
    from workbench.learn.config import EvaluateSettings
    from workbench.params import load_settings

    opts = load_settings(EvaluateSettings, args.config, "evaluate")
    lines = evaluate_to_files(data=args.data, split_path=args.split, out=args.out, figures=args.figures,
                              model=args.model or opts.model, also=args.also, options=opts,
                              mlflow_log=not args.no_mlflow, dvc_stage=args.dvc_stage, tracking_uri=args.tracking_uri)
    for line in lines:
        info(line)
    return 0


def load_model_spec(spec: str, tracking_uri: str | None = None):
    """A model folder path, or any ``load_leg_model`` spec (``lstm``, ``ef``, ``models:/...``).

    Registry specs (``lstm``, ``models:/...``) resolve in ``tracking_uri`` (default: the project's store).
    """
    from pathlib import Path

    from workbench.hydro.legmodel import load_leg_model

    if Path(spec).is_dir():
        from workbench.learn.registry import load_folder

        return load_folder(spec, model_uri=str(spec), model_path=str(spec))
    if tracking_uri and (spec == "lstm" or spec.startswith("models:")):
        return load_leg_model(spec, tracking_uri=tracking_uri)
    return load_leg_model(spec)


def evaluate_to_files(*, data, split_path, out, figures, model, also, options, mlflow_log=True,
                      dvc_stage=None, tracking_uri=None) -> list[str]:
    """Load data, split and models; score; write the metrics JSON and figures atomically; log to MLflow."""
    from workbench.atomic import write_json
    from workbench.learn.evaluate import evaluate_models
    from workbench.learn.metrics import mse_ratios
    from workbench.learn.windows import read_table

    split = _read_split(split_path)
    table = read_table(data)
    models = _load_models(model, also, tracking_uri)
    sources = _model_sources(models)
    metrics, result = evaluate_models(table, split, models)
    write_json(out, metrics)
    ratios = mse_ratios(metrics)
    lines = _summary_lines(out, metrics, result, sources, ratios)
    written = []
    if figures:
        written = _write_figures(figures, table, result, metrics, options)
        lines.append(f"figures: {', '.join(str(p) for p in written)}")
    if mlflow_log:
        lines.append(_log_evaluation(metrics, ratios, models["lstm"], table, out, written, options, dvc_stage,
                                     tracking_uri))
    return lines


def _read_split(split_path):
    """The ``ParameterSplit`` recorded in split.json; a missing or malformed file is a ``ContractError``."""
    import json
    from pathlib import Path

    from workbench.errors import ContractError
    from workbench.learn.split import ParameterSplit

    sp = Path(split_path)
    if not sp.is_file():
        raise ContractError("split file not found", path=sp, hint="workbench train writes <model folder>/split.json")
    try:
        return ParameterSplit.from_dict(json.loads(sp.read_text(encoding="utf-8")), str(sp))
    except (json.JSONDecodeError, KeyError, TypeError) as exc:
        raise ContractError(f"not a split record ({type(exc).__name__})", path=sp) from exc


def _load_models(model, also, tracking_uri) -> dict:
    """The models to score, by name: the EF, the learned model ``lstm`` and each ``--also NAME=SPEC``."""
    from workbench.errors import ContractError
    from workbench.hydro.legmodel import load_leg_model

    models = {"ef": load_leg_model("ef"), "lstm": load_model_spec(model, tracking_uri)}
    for item in also:
        name, _, spec = item.partition("=")
        if not spec:
            raise ContractError(f"--also {item!r} is not NAME=SPEC")
        models[name] = load_model_spec(spec, tracking_uri)
    return models


def _model_sources(models) -> list[str]:
    """Which registry version or folder each learned model came from (models with neither are left out)."""
    sources = []
    for name, m in models.items():
        d = m.describe()
        if d.get("model_version"):
            sources.append(f"{name}: {d.get('model_uri')} version {d['model_version']}")
        elif d.get("model_path") or d.get("model_uri"):
            sources.append(f"{name}: {d.get('model_path') or d.get('model_uri')}")
    return sources


def _summary_lines(out, metrics, result, sources, ratios) -> list[str]:
    """The printed summary: what was written, the models' sources, MSE ratios and EF R^2 per flow speed."""
    lines = [f"wrote {out}: {metrics['lstm']['n_runs']} held-out runs, {metrics['lstm']['n_ticks']} ticks per model "
             f"(first {result['skip']} ticks of each run skipped for all models)"]
    if sources:
        lines.append("models: " + "; ".join(sources))
    for s, r in ratios.items():
        r2 = metrics["ef"]["r2_by_flow_speed"][s]
        lines.append(f"  flow {s} m/s: MSE LSTM/EF " + "  ".join(f"{c} {v:.2f}" for c, v in r.items()) +
                     f"   EF R^2 fy {r2['fy_n']:.2f} fz {r2['fz_n']:.2f}")
    lines.append("  all speeds: EF R^2 " + "  ".join(f"{c} {metrics['ef']['r2'][c]:.2f}" for c in ("fy_n", "fz_n",
                                                                                                    "tx_nm")))
    return lines


def _write_figures(figures, table, result, metrics, options) -> list:
    """Draw the prediction curves and the MSE box plot and swap them into ``figures`` as one set; their paths."""
    from pathlib import Path

    from workbench.atomic import atomic_dir
    from workbench.learn.evaluate import prediction_figures
    from workbench.learn.figures import mse_boxplot

    figs = prediction_figures(table, result, metrics, options.figure_sets, options.figure_flow_speed_mps,
                              options.figure_cycles)
    names = [f"prediction_{chr(ord('a') + i)}.png" for i in range(len(figs))]
    figs.append(mse_boxplot(metrics, options.boxplot_channels))
    names.append("mse_boxplot.png")
    folder = Path(figures)
    # the figures are one set, swapped in together; no marker file: DVC draws every file of this plots folder
    with atomic_dir(folder, verb="evaluate", marker=False) as tmp:
        for fig, name in zip(figs, names, strict=False):
            fig.savefig(tmp / name, dpi=110, format="png")
    return [folder / name for name in names[:len(figs)]]


def _log_evaluation(metrics, ratios, lstm, table, out, figures, options, dvc_stage, tracking_uri=None) -> str:
    from pathlib import Path

    from workbench.tracking import log_artifacts, log_metrics, run_name, run_tags, tracked_run

    experiment = options.experiment
    d = lstm.describe()
    tags = run_tags(kind="evaluate", campaigns=table.campaigns(), variant=d.get("variant"), dvc_stage=dvc_stage,
                    model_uri=d.get("model_uri"), model_run_id=d.get("run_id"), model_version=d.get("model_version"),
                    model_path=d.get("model_path"))
    uri = str(d.get("model_uri") or d.get("model_path") or "lstm")
    label = uri.removeprefix("models:/") if uri.startswith("models:/") else Path(uri).name
    if d.get("model_version") and "@" in label:
        label += f" v{d['model_version']}"
    flat = {}
    for name, m in metrics.items():
        for c, v in m["mse"].items():
            flat[f"{name}_mse_{c}"] = v
        for c, v in m["r2"].items():
            flat[f"{name}_r2_{c}"] = v
        for s, chans in m["mse_by_flow_speed"].items():
            for c, v in chans.items():
                flat[f"{name}_mse_{s}_{c}"] = v
    for s, chans in ratios.items():
        for c, v in chans.items():
            flat[f"ratio_lstm_ef_mse_{s}_{c}"] = v
    with tracked_run(name=run_name("evaluate", label, table.campaigns(), dvc_stage), tags=tags, experiment=experiment,
                     tracking_uri_=tracking_uri) as run:
        log_metrics(flat)
        log_artifacts([out])
        log_artifacts(figures, under="figures")
    return f"MLflow: evaluate run {run.info.run_id} in experiment {experiment}"
