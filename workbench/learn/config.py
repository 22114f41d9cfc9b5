"""The learning configuration: one frozen dataclass tree read from ``pipelines/learn.yaml``.

``train(cfg)``, the Optuna objective and the tests all take a :class:`LearnSettings`; the CLI
builds it from the YAML file plus ``--set key=value`` overrides (dotted keys, YAML values), and
the tests build the real one and shrink it. The tree is built by :func:`workbench.params.build`:
an unknown key (in the file or a ``--set``) is a :class:`~workbench.errors.ParamsError` naming the
file, the key path (``train.model.hiden_size``) and the allowed keys, so a typo in the YAML is an
error, not a silently ignored knob.

Settings classes end in ``Settings`` (issue 17); the earlier names (``LearnConfig``, ``DataCfg``,
...) stay as aliases.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

from workbench.errors import ContractError, ParamsError, SettingError
from workbench.threads import check_setting

#: model variants: recurrent backbones, a window MLP, and the EF-residual hybrid
VARIANTS = ("lstm", "gru", "mlp", "ef_residual")
#: model inputs per tick, in order (paper: V_flow, theta_H, theta_K, omega_H, omega_K)
FEATURES = ("flow_speed_mps", "theta_h_deg", "theta_k_deg", "omega_h_dps", "omega_k_dps")


@dataclass(frozen=True)
class SplitSettings:
    """7:1:2 split by motion-parameter set, seeded; ``pin_test`` forces one matching set each into test."""

    fractions: tuple[float, float, float] = (0.7, 0.1, 0.2)
    seed: int = 0
    #: partial parameter specs (e.g. the paper's figure sets); one matching set of each goes to test
    pin_test: tuple[Mapping[str, float], ...] = ()
    #: parameters whose values val and test each take in proportion (e.g. ("frequency_hz",)); () plain draw
    stratify: tuple[str, ...] = ()


@dataclass(frozen=True)
class DataSettings:
    """Where the windows come from and how they are drawn."""

    paths: tuple[str, ...] = ()
    seq_len: int = 16
    split: SplitSettings = field(default_factory=SplitSettings)
    #: training windows drawn at random (without replacement) per epoch; None: every window
    train_windows_per_epoch: int | None = None
    batch_size: int = 256
    eval_batch_size: int = 4096


@dataclass(frozen=True)
class ModelSettings:
    """The network: paper FED-LSTM = lstm, 2 layers of 64, dropout 0.21."""

    variant: str = "lstm"
    hidden_size: int = 64
    num_layers: int = 2
    dropout: float = 0.21
    #: backbone of the ef_residual hybrid (lstm | gru | mlp)
    backbone: str = "lstm"


@dataclass(frozen=True)
class OptimSettings:
    """Adam with the learning rate reduced on validation-loss plateaus, kept within [lr_min, lr_max]."""

    lr: float = 0.01
    lr_min: float = 1e-3
    lr_max: float = 1e-1
    weight_decay: float = 0.0
    plateau_factor: float = 0.5
    plateau_patience: int = 1
    grad_clip: float = 1.0


@dataclass(frozen=True)
class TrainerSettings:
    """Epochs, stopping and seeding."""

    max_epochs: int = 20
    early_stop_patience: int = 4
    max_time_s: float | None = None
    seed: int = 0
    #: torch intra-op threads while training: a number, None (torch's default, one per core) or
    #: "auto" (the cores idle when training starts: more threads on a core another job holds run
    #: slower than one; measured, docs/learning.md)
    torch_threads: int | str | None = "auto"


@dataclass(frozen=True)
class TrackingSettings:
    """MLflow: where runs go, how they are named, what gets registered."""

    enabled: bool = True
    tracking_uri: str | None = None
    experiment: str = "fed-lstm"
    run_name: str | None = None
    registered_model: str = "fed-lstm"
    alias: str = "champion"
    register: bool = True
    dvc_stage: str | None = None


@dataclass(frozen=True)
class LearnSettings:
    """Everything ``train(cfg)`` needs."""

    data: DataSettings = field(default_factory=DataSettings)
    model: ModelSettings = field(default_factory=ModelSettings)
    optim: OptimSettings = field(default_factory=OptimSettings)
    trainer: TrainerSettings = field(default_factory=TrainerSettings)
    tracking: TrackingSettings = field(default_factory=TrackingSettings)
    #: folder the trained model is written to (weights, config, normalisation, split, metrics); None: none
    model_dir: str | None = None

    def validate(self, *, path: str | Path | None = None, key: str = "train") -> "LearnSettings":
        """Refuse values no model can train with (a one-line ParamsError naming the file and key path)."""
        m, d, o = self.model, self.data, self.optim

        def bad(where: str, fault: str, hint: str | None = None) -> ParamsError:
            return ParamsError(fault, path=path, where=f"{key}.{where}", hint=hint)

        if m.variant not in VARIANTS:
            raise bad("model.variant", f"unknown variant {m.variant!r}", f"one of {', '.join(VARIANTS)}")
        if m.backbone not in ("lstm", "gru", "mlp"):
            raise bad("model.backbone", f"unknown backbone {m.backbone!r}", "lstm, gru or mlp")
        for where, value in (("data.seq_len", d.seq_len), ("model.hidden_size", m.hidden_size),
                             ("model.num_layers", m.num_layers), ("data.batch_size", d.batch_size)):
            if value < 1:
                raise bad(where, f"must be >= 1, got {value}")
        if not 0 <= m.dropout < 1:
            raise bad("model.dropout", f"{m.dropout} outside [0, 1)")
        if not 0 < o.lr_min <= o.lr_max:
            raise bad("optim.lr_min", f"lr_min {o.lr_min} / lr_max {o.lr_max} inconsistent")
        try:
            check_setting(self.trainer.torch_threads)
        except SettingError as exc:  # the same error, with the file and key path added
            raise exc.located(path=path, where=f"{key}.trainer.torch_threads") from None
        fr = d.split.fractions
        if len(fr) != 3 or min(fr) < 0 or abs(sum(fr) - 1) > 1e-6 or fr[0] == 0:
            raise bad("data.split.fractions", f"{list(fr)} must be three non-negative numbers summing to 1")
        return self

    def to_dict(self) -> dict:
        """Plain nested dict (JSON/YAML-serialisable)."""
        return _plain(dataclasses.asdict(self))

    def with_overrides(self, overrides: Sequence[str] | Mapping[str, Any]) -> "LearnSettings":
        """A copy with dotted-key overrides applied (``["model.hidden_size=96"]`` or a mapping).

        An unknown key is a ParamsError naming its key path (``train.model.hiden_size``) and the allowed keys.
        """
        import yaml

        from workbench.params import set_dotted

        items = overrides.items() if isinstance(overrides, Mapping) else [_split_override(s) for s in overrides]
        doc = self.to_dict()
        for key, value in items:
            if isinstance(value, str) and not isinstance(overrides, Mapping):
                value = yaml.safe_load(value)
            set_dotted(doc, key, value, section="train")
        return config_from_dict(doc)


def _split_override(s: str) -> tuple[str, str]:
    if "=" not in s:
        raise ContractError(f"override {s!r} is not key=value", hint="e.g. --set model.hidden_size=96")
    k, _, v = s.partition("=")
    return k.strip(), v


def _plain(x):
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    return x


def config_from_dict(doc: Mapping[str, Any] | None, *, path: str | Path | None = None,
                     key: str = "train") -> LearnSettings:
    """Build and validate :class:`LearnSettings` from a nested mapping (the YAML's ``train`` section).

    Built by :func:`workbench.params.build`: unknown keys and wrong types are a ParamsError naming
    ``path`` and the key path under ``key``.
    """
    from workbench.params import build

    return build(LearnSettings, doc, key=key, path=path).validate(path=path, key=key)


def load_config(path: str | Path = "pipelines/learn.yaml", overrides: Sequence[str] = ()) -> LearnSettings:
    """The ``train`` section of the learning parameter file, with overrides applied."""
    from workbench.params import read_section

    raw, source = read_section(path, "train")
    cfg = config_from_dict(raw, path=source)
    return cfg.with_overrides(overrides) if overrides else cfg


def load_section(path: str | Path, section: str) -> dict:
    """Another section of the learning parameter file (``tune``, ``evaluate``) as a dict."""
    from workbench.params import read_section

    return read_section(path, section)[0]


@dataclass(frozen=True)
class EvaluateSettings:
    """The ``evaluate`` section of ``pipelines/learn.yaml`` (``workbench evaluate``)."""

    #: the learned model scored against the EF (registry alias, URI or folder)
    model: str = "lstm"
    #: partial parameter specs of the prediction figures' runs (the paper's Fig. 4 sets)
    figure_sets: tuple[Mapping[str, float], ...] = ()
    #: the run shown in the prediction figures (nearest measured speed; None: the first)
    figure_flow_speed_mps: float | None = None
    figure_cycles: float = 2.0
    boxplot_channels: tuple[str, ...] = ("fy_n", "fz_n", "tx_nm")
    #: MLflow experiment of the evaluate run
    experiment: str = "fed-lstm"


#: the names before issue 17 (settings classes end in ``Settings``); kept for existing imports
LearnConfig = LearnSettings
SplitCfg = SplitSettings
DataCfg = DataSettings
ModelCfg = ModelSettings
OptimCfg = OptimSettings
TrainerCfg = TrainerSettings
TrackingCfg = TrackingSettings


def cli_config(args) -> LearnSettings:
    """The training configuration a verb's common options describe (``--config``, ``--data``, ``--set``, ...)."""
    cfg = load_config(args.config, getattr(args, "set", None) or ())
    over: dict[str, Any] = {}
    if getattr(args, "data", None):
        over["data.paths"] = list(args.data)
    if getattr(args, "tracking_uri", None):
        over["tracking.tracking_uri"] = args.tracking_uri
    if getattr(args, "experiment", None):
        over["tracking.experiment"] = args.experiment
    if getattr(args, "no_mlflow", False):
        over["tracking.enabled"] = False
    if getattr(args, "dvc_stage", None):
        over["tracking.dvc_stage"] = args.dvc_stage
    cfg = cfg.with_overrides(over) if over else cfg
    if not cfg.data.paths:
        raise ContractError("no processed data given", path=args.config,
                            hint="pass --data datasets/processed/<campaign>.parquet or set train.data.paths")
    return cfg


def add_common_options(p, *, data_required: bool = False) -> None:
    """``--config``, ``--data``, ``--set``, ``--tracking-uri``, ``--experiment``, ``--no-mlflow``, ``--dvc-stage``."""
    p.add_argument("--config", default="pipelines/learn.yaml", help="learning parameter file (default: %(default)s)")
    p.add_argument("--data", nargs="+", metavar="PARQUET", required=data_required,
                   help="processed tunnel Parquet file(s) or folder(s) of them, one or more campaigns "
                        "(contract section 3)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a key of the file's train section, e.g. --set model.variant=gru (repeatable)")
    p.add_argument("--tracking-uri", help="MLflow tracking URI (default: MLFLOW_TRACKING_URI, else sqlite:///mlflow.db "
                                          "in the project); e.g. http://mlflow.lab:5000")
    p.add_argument("--experiment", help="MLflow experiment (default: the file's tracking.experiment)")
    p.add_argument("--no-mlflow", action="store_true", help="do not record in MLflow (and do not register)")
    p.add_argument("--dvc-stage", help="dvc_stage tag of the MLflow runs (default: DVC_STAGE, else 'manual')")
