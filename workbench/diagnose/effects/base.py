"""What an effect is: its stage in the chain, its terms, and every hook the loop asks it through.

An :class:`Effect` is one physical mechanism the diagnosed model may lack, with the canonical
name and parameters of the effect table (docs/diagnose.md). It acts at one *stage* of the
chain from commanded motion to load-cell reading:

``input``   changes the motion the model sees (servo lag);
``force``   adds fluid or gravity loads: linear terms ``param * column`` computed from the
            kinematics, a fixed term (circulatory lag), or per-run columns (flow tone);
``filter``  passes the wrench through a linear filter (structural resonance);
``sensor``  acts in the load cell: crosstalk between channels, drift.

Linear parameters are fitted by weighted least squares on the columns; nonlinear ones (a time
constant, a frequency) by a search that wraps the linear fit (:class:`SearchParam`). Effects
name their terms readably (:meth:`Effect.get_feature_names`) and compose with ``+`` into an
:class:`EffectLibrary`, the candidate set the selection draws from.

Everything particular to one effect lives on its class: its constructor options
(:meth:`Effect.options`, :attr:`Effect.library_options`), the evidence clause that points at it
(:meth:`Effect.hint`), its configuration on the campaign (:meth:`Effect.configure`), its
structural checks (:meth:`Effect.check`, :meth:`Effect.refusal`), the frequencies it proposes
(:meth:`Effect.proposals`) and explains, how it acts on a model's output in a surrogate search
(:meth:`Effect.on_output`, :meth:`Effect.flow_factor`). The loop, the selection and the problem
ask these hooks and never an effect's name. This module imports no effect module (the effect
modules import it; :mod:`workbench.diagnose.library` finds them through the plug-in table).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Callable

import numpy as np

from workbench.diagnose.evidence import locked_clause
from workbench.hydro.motion import LegMotion

STAGES = ("input", "force", "filter", "sensor")


@dataclass(frozen=True)
class SearchParam:
    """A nonlinear parameter: its search grid (coarse, then refined within ``bounds``)."""

    name: str
    grid: tuple[float, ...]
    bounds: tuple[float, float]
    log: bool = False


@dataclass
class Terms:
    """What an effect adds at its stage for one batch: linear columns, a fixed part, per-run columns.

    Columns are wrenches ``(B, T, 6)`` of a unit parameter; ``support`` lists the channels in
    which each column can be nonzero (crosstalk and drift touch one channel each).

    ``predict``: where the model predicts with other columns than those it is fitted and judged
    on, the predicting ones by name (a drift is fitted on each run's settled span, its level
    there taken out, and predicts ``rate * t``); None: the same. ``local_owner``: per per-run
    column of the sensor stage, the linear parameter it goes with (a fit that leaves that
    entry out leaves the column out too); empty: none. ``fit_offset``: a known part of the
    reading (B, T, 6) the fits take off before fitting the columns and that the prediction
    leaves to ``predict`` (a drift's level in each run at its current rate); None: none.
    """

    names: list[str] = field(default_factory=list)
    cols: list[np.ndarray] = field(default_factory=list)
    support: list[np.ndarray] = field(default_factory=list)
    fixed: np.ndarray | None = None
    local_names: list[str] = field(default_factory=list)
    local: list[np.ndarray] = field(default_factory=list)
    predict: dict[str, np.ndarray] | None = None
    local_owner: list[str] = field(default_factory=list)
    fit_offset: np.ndarray | None = None


class Context:
    """What effects see of one batch of runs under one configuration (motion after input effects)."""

    def __init__(self, rs, model, motion: LegMotion, geometry, rho_kgpm3: float = 1000.0):
        self.rs = rs
        self.model = model
        self.motion = motion
        self.geometry = geometry
        self.rho = rho_kgpm3
        self._flow_cache: dict[float, np.ndarray] = {}
        #: the current values of the linear coefficients (qualified names), set before the sensor stage
        self.coefs: dict[str, float] = {}
        #: what the fits compare residuals and columns through (an equation-error filter effect's inverse;
        #: :meth:`Effect.compare_filter`), set before the sensor stage; None: as read
        self.compare: Callable[[np.ndarray], np.ndarray] | None = None

    @property
    def dt_s(self) -> float:
        """Tick interval."""
        return self.motion.dt_s

    @property
    def time_s(self) -> np.ndarray:
        """(B, T) time since the run's first trigger edge."""
        return self.rs.time_s

    @cached_property
    def kin(self):
        """Kinematics of the (transformed) motion."""
        from workbench.diagnose.flowterms import LegKinematics

        return LegKinematics(self.motion, self.geometry, self.rho)

    @cached_property
    def base(self) -> np.ndarray:
        """The diagnosed model's wrench on the (transformed) motion."""
        return np.asarray(self.model.wrench(self.motion), float)

    def wrench_at_flow(self, factor: float) -> np.ndarray:
        """The model's wrench with every flow speed scaled by ``factor`` (cached)."""
        if factor == 1.0:
            return self.base
        if factor not in self._flow_cache:
            m = self.motion
            scaled = LegMotion(m.dt_s, m.theta_h_deg, m.theta_k_deg, m.omega_h_dps, m.omega_k_dps,
                               m.flow_speed_mps * factor, m.alpha_h_dps2, m.alpha_k_dps2)
            self._flow_cache[factor] = np.asarray(self.model.wrench(scaled), float)
        return self._flow_cache[factor]


ALL_CHANNELS = np.ones(6, bool)


class Effect:
    """Base class of candidate effects; subclasses set the class attributes and override the hooks they need."""

    #: canonical snake_case name (the effect table)
    name: str = ""
    stage: str = "force"
    #: part of the physical leg (kept in the model handed to the simulator); rig artefacts are not
    physical: bool = True
    #: the effect's formula in one line (report and docs)
    formula: str = ""
    #: nonlinear parameters found by search
    search: tuple[SearchParam, ...] = ()
    #: drop individually insignificant linear terms after selection (crosstalk entries, drift channels)
    prunable: bool = False
    #: needs a frequency proposed by the residual evidence (a narrowband peak) to be a candidate
    needs_peak: bool = False
    #: sensor columns read the predicted true wrench, so fits iterate the force coefficients (crosstalk)
    reads_prediction: bool = False
    #: canonical parameters that locate the effect rather than measure its size (their interval may hold zero)
    location_params: tuple[str, ...] = ()
    #: library settings (``pipelines/diagnose.yaml`` section ``library``) passed to the constructor: key -> keyword
    library_options: dict[str, str] = {}
    #: an input effect whose action on a causal model's output is known to first order
    #: (:meth:`on_output`, :meth:`flow_factor`), so an expensive model's search may use the output
    surrogate_ok: bool = False
    #: physically plausible range of each canonical parameter (a fit outside absorbs something else)
    ranges: dict[str, tuple[float, float]] = {}
    #: the effect changes what every other term sees (a servo's delay moves every force column): when
    #: it is acceptable at a step but another effect wins, the selection also follows the path that
    #: takes it there (a force effect taken first absorbs its misfit channel by channel)
    lookahead: bool = False
    #: the effect's searched values set the phase of the whole prediction (a delay, a low-pass mode): two
    #: such effects trade off (below a mode, its damping's phase is a delay's), so the final check judges
    #: each against the others' values searched again without it (a profile likelihood), not held at the
    #: values they took beside it
    timing: bool = False
    #: judged cross-fitted (``SelectionSettings.judge_folds``): every parameter set held out once, not only the
    #: split's. For an effect whose judgement competes with a base model's misfit that differs from set to set
    #: (a crosstalk beside a learned model's misfit), where a few held-out sets decide by their luck
    crossfit: bool = False

    # ------------------------------------------------------------------ composition
    def __add__(self, other: "Effect | EffectLibrary") -> "EffectLibrary":
        return EffectLibrary([self]) + other

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"

    def get_feature_names(self) -> list[str]:
        """Readable names of this effect's terms (``effect: formula``)."""
        names = [f"{self.name}.{p}" for p in self.linear_names()]
        names += [f"{self.name}.{s.name} (searched)" for s in self.search]
        return [f"{n}  [{self.formula}]" for n in names] or [f"{self.name}  [{self.formula}]"]

    def linear_names(self) -> list[str]:
        """Names of the linear parameters (a crosstalk or drift effect lists every entry it may fit)."""
        return []

    def default_nl(self) -> dict[str, float]:
        """Starting values of the nonlinear parameters."""
        return {s.name: float(np.median(s.grid)) for s in self.search}

    # -------------------------------------------------------------------- options
    def options(self) -> dict:
        """Constructor options (JSON-serialisable), so a saved model rebuilds the effect exactly."""
        return {}

    @classmethod
    def from_options(cls, options: dict | None = None) -> "Effect":
        """Build from :meth:`options` (as read back from JSON)."""
        return cls(**dict(options or {}))

    # ----------------------------------------------------------------- the chain
    def transform_motion(self, motion: LegMotion, nl: dict) -> LegMotion:
        """Input stage: the motion the leg really made."""
        return motion

    def force_terms(self, ctx: Context, nl: dict) -> Terms:
        """Force stage: linear columns, fixed part and per-run columns."""
        return Terms()

    def filter_wrench(self, w: np.ndarray, dt_s: float, nl: dict) -> np.ndarray:
        """Filter stage: the wrench (..., B, T, 6) through the effect (linear in ``w``)."""
        return w

    def compare_filter(self, nl: dict, dt_s: float) -> Callable[[np.ndarray], np.ndarray] | None:
        """Filter stage, equation-error form: the filter residuals are compared through while the effect is active.

        None (default): the residual is compared as read. A filter effect whose input carries the
        base model's own misfit returns its inverse (linear, along axis -2 of (..., B, T, 6)): the
        fit then compares the reading through the inverse with the unfiltered prediction.
        """
        return None

    def sensor_terms(self, ctx: Context, nl: dict, prediction: np.ndarray) -> Terms:
        """Sensor stage: columns that may depend on the predicted true wrench."""
        return Terms()

    def reading_inverse(self, nl: dict, coefs: dict[str, float], dt_s: float) -> Callable[[np.ndarray], np.ndarray] | None:
        """Filter and sensor stages: the map taking a residual of the reading back to the true wrench's.

        The reading is the true wrench through the claimed sensor-side effects, so the model's
        residual in the reading is that map applied to its residual in the true wrench; the
        inverse (along axis -2 of (..., T, 6)) gives the error against the readings corrected by
        the claimed effects (``mse_after_corrected``). ``coefs``: every fitted coefficient
        (qualified names). None (default): not invertible, and no corrected error is reported.
        """
        return None

    def on_output(self, w: np.ndarray, dt_s: float, nl: dict) -> np.ndarray:
        """An input effect acting on a causal model's output ``w`` (..., T, 6) to first order (identity)."""
        return w

    def flow_factor(self, nl: dict) -> float:
        """The factor an input effect puts on the flow speed the model sees (1: none)."""
        return 1.0

    # ---------------------------------------------------------------- the fit
    def configure(self, sample: Callable[[], tuple[np.ndarray, np.ndarray]]) -> "Effect":
        """The effect as fitted on this campaign, once before selection (itself by default).

        ``sample()`` returns the base model's predicted wrench (B, T, 6) on a batch of training
        runs and the mask of fitted ticks (B, T); it is computed only when an effect asks.
        """
        return self

    def canonical_params(self, coefs: dict[str, float], nl: dict[str, float],
                         cov: dict[tuple[str, str], float], local: dict | None = None) -> tuple[dict, dict]:
        """Canonical parameters and their standard errors from the fitted values.

        ``cov`` holds the covariance of linear and (linearised) nonlinear parameters by name
        pair; ``local`` the per-run columns' values, information and flow speeds by name
        (``(values, information, flow_mps)``, arrays over runs), None when the effect has none.
        """
        params = {**nl, **coefs}
        se = {k: float(np.sqrt(max(cov.get((k, k), np.nan), 0.0))) if (k, k) in cov else float("nan")
              for k in params}
        return params, se

    def range_of(self, name: str) -> tuple[float, float] | None:
        """The plausible range of canonical parameter ``name`` (a ``ranges`` key, or a ``prefix*`` pattern); None: any."""
        return self.ranges.get(name) or next((r for pat, r in self.ranges.items()
                                              if pat.endswith("*") and name.startswith(pat[:-1])), None)

    def negligible_of(self, name: str) -> float:
        """Half-width of the band around zero a claim's interval of magnitude parameter ``name`` must clear.

        0 (the default): zero itself. An effect whose sizes have a floor below which no claim means
        anything overrides it (the crosstalk's option ``floor``).
        """
        return 0.0

    def implausible(self, params: dict) -> str | None:
        """Why the fitted canonical parameters are not this effect (None when they are plausible)."""
        for k, v in params.items():
            rng = self.range_of(k)
            if rng and v is not None and np.isfinite(v) and not rng[0] <= v <= rng[1]:
                return f"{k} = {v:.3g} is outside the plausible range [{rng[0]:g}, {rng[1]:g}]"
        return None

    def searched(self, nl: dict, problem, config, coefs: dict, names: list[str]) -> dict:
        """The searched values as the effect takes them (itself by default).

        An effect whose search criterion is known to be biased corrects the optimum here
        (``problem``: the fitting problem; ``config``: the configuration without the effect, with
        ``coefs`` and ``names`` its linear fit).
        """
        return nl

    def search_grams(self, problem, config, coefs: dict, names: list[str]):
        """A faster objective for this effect's search: ``nl -> Grams`` on the search runs (None: the plain one).

        The plain search builds the whole design of ``config`` plus this effect at every
        evaluation (``Problem.grams``). An effect whose searched values enter the fit through a
        few fixed arrays may build them once here (``config``: without the effect; ``names``: the
        columns fitted, with the effect's own). Only the search's criterion may change by it: the
        candidate is fitted and judged through the plain design afterwards.
        """
        return None

    def search_reading(self, nl: dict, dt_s: float) -> Callable[[np.ndarray], np.ndarray] | None:
        """Filter stage, once claimed: a faster criterion for the searches of other effects beside it.

        A map taking the reading (..., B, T, 6) to what the design *without* this effect is compared
        with while another effect's values are searched (screening candidates only, like
        :meth:`search_grams`; their fits and judgements keep the whole design). None (default):
        the search passes the whole design through the effect at every evaluation.
        """
        return None

    def seed(self, problem, config=None) -> tuple[dict, str] | None:
        """Searched values the campaign's own evidence points to, apart from any fit: ``(nl, why)`` or None.

        A look-ahead effect (:attr:`lookahead`) that the greedy path never takes may have been hidden
        by force effects that took its misfit first; with a seed, the selection also follows the path
        that starts from the effect at these values (held at step 1, then followed like any chosen
        look-ahead effect), and keeps it only when its final held-out fit beats the greedy one's.
        ``why``: one line for the selection record; ``config``: the configuration the paths ended with
        (evidence it already explains is no seed). None (default): no such evidence.
        """
        return None

    def refusal(self, params: dict, settings) -> str | None:
        """Why these fitted values are another effect in disguise (None when they are not).

        ``settings``: the selection settings (:class:`~workbench.diagnose.selection.SelectionSettings`).
        """
        return None

    def null_variants(self, nl: dict) -> list[dict]:
        """Parameter values that should explain nothing (the null of per-run nuisance fits)."""
        return []

    def telling_runs(self, nl: dict, rs) -> np.ndarray | None:
        """Per run of the batch ``rs``: whether it can tell the effect from the base model's misfit (None: all can).

        A per-run fit judged against its :meth:`null_variants` fits the runs that cannot tell
        (a flow tone on a gait harmonic) with the same columns as its variants; its held-out gain
        is counted over the runs that can.
        """
        return None

    def judged_as(self, nl: dict) -> dict | None:
        """The values the effect is judged under on held-out runs, when they differ from ``nl`` (None: ``nl``).

        An effect whose held-out test needs per-run nuisance columns beside it (a drift, beside
        each run's level) adds them only under these values, and its :meth:`null_variants` of
        them give the same nuisance alone; the model keeps ``nl``.
        """
        return None

    def judging_names(self, nl: dict, names: list[str]) -> list[str]:
        """Shared columns the effect adds under its judging values ``nl`` beside its kept entries ``names`` (qualified).

        Fitted on the training runs with the entries and judged on held-out runs like them, and
        kept in the null variants (a crosstalk judged beside the other channels' residuals); the
        model never holds them. Names without the effect's prefix; none by default.
        """
        return []

    # ------------------------------------------------------------- the evidence
    def hint(self, ev, params: dict) -> str:
        """The clause of residual evidence (:class:`~workbench.diagnose.evidence.Evidence`) that points here."""
        return locked_clause(ev)

    def proposals(self, probe, config, fit) -> list:
        """Frequencies (evidence peaks) a ``needs_peak`` effect is tried at: the residual's narrowband lines.

        ``probe``: the loop's view of the residuals (:class:`~workbench.diagnose.loop.Probe`).
        """
        return probe.peaks_of(config, fit)

    def check(self, cand, probe, config, fit) -> str | None:
        """A structural check of a fitted candidate against the evidence (None: it passes)."""
        return None

    def practical_gain(self, gain_c: np.ndarray) -> np.ndarray:
        """The held-out gain per channel that the claim's ``min_gain`` is held against.

        By default the share of the whole held-out residual the effect removes. An effect that can
        only remove part of the residual (a flow tone: nothing that repeats every stroke) may
        count its gain against that part.
        """
        return gain_c

    def complete(self, params: dict, stderr: dict, problem, config, residuals: list) -> None:
        """Fill canonical parameters only the final residuals tell (in place); nothing by default."""

    def explained_frequencies(self, params: dict) -> list[float]:
        """Residual lines this claimed effect accounts for (not reported as unexplained)."""
        return []

    def notes(self, coefs: dict[str, float]) -> list[str]:
        """Remarks on the fitted parameters for the report (what an entry stands for)."""
        return []

    # ------------------------------------------------------------- a virtual truth
    @classmethod
    def truth_params(cls, t) -> dict[str, float] | None:
        """This effect's canonical parameters in a virtual campaign's rich truth (None: it has no counterpart).

        ``t``: :class:`workbench.diagnose.library.TruthView`, the truth's parameters, geometry and
        the quantities several effects share (the plate's added mass, the links' masses, ...).
        """
        return None

    @classmethod
    def truth_notes(cls, t) -> dict[str, str]:
        """Where :meth:`truth_params` is only the nearest reading of the truth: a note per parameter."""
        return {}


class EffectLibrary:
    """A composable set of candidate effects (``a + b + c``)."""

    def __init__(self, effects: list[Effect] | None = None):
        self.effects: list[Effect] = list(effects or [])
        names = [e.name for e in self.effects]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            from workbench.errors import ModelError

            raise ModelError(f"effect library lists {sorted(dup)} twice")

    def __add__(self, other: "Effect | EffectLibrary") -> "EffectLibrary":
        extra = other.effects if isinstance(other, EffectLibrary) else [other]
        return EffectLibrary(self.effects + list(extra))

    def __iter__(self):
        return iter(self.effects)

    def __len__(self) -> int:
        return len(self.effects)

    def __getitem__(self, name: str) -> Effect:
        for e in self.effects:
            if e.name == name:
                return e
        raise KeyError(name)

    def names(self) -> list[str]:
        """Effect names in library order."""
        return [e.name for e in self.effects]

    def get_feature_names(self) -> list[str]:
        """Every term of every effect, readable."""
        return [n for e in self.effects for n in e.get_feature_names()]

    def without(self, *names: str) -> "EffectLibrary":
        """The library less some effects."""
        return EffectLibrary([e for e in self.effects if e.name not in names])

    def configured(self, sample: Callable[[], tuple[np.ndarray, np.ndarray]]) -> "EffectLibrary":
        """Every effect configured on the campaign (:meth:`Effect.configure`), ``sample`` computed at most once."""
        memo: list = []

        def once():
            if not memo:
                memo.append(sample())
            return memo[0]

        return EffectLibrary([e.configure(once) for e in self.effects])
