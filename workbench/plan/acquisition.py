"""Which runs teach the model most where the gaits swim: integrated posterior variance over an ensemble.

The shape of BoTorch's ``qNegIntegratedPosteriorVariance``: the value of a batch of new runs is how
much it lowers the posterior variance of the model, integrated (weighted) over points drawn from
the region of interest. BoTorch needs a GP posterior (and pulls in gpytorch); the FED-LSTM's
uncertainty is a deep ensemble, so the posterior is written here over the ensemble, in numpy:

* the prior covariance between any two states x, y (region ticks and the ticks a candidate run
  would record), per channel, is the members' sample covariance, *localised* by a Gaussian taper
  in state space, ``k_c(x, y) = cov_k(f_k,c(x), f_k,c(y)) * exp(-|x - y|^2 / (2 l^2))`` (the
  ensemble-Kalman localisation: K members alone give a rank K-1 covariance, which would make every
  run after the first few look useless; the taper keeps the members' correlations between nearby
  states and drops spurious far ones). States are the model inputs in the training normalisation;
* a candidate run is observed at ``points_per_run`` ticks of its steady cycle, each standing for
  ``ticks / points`` readings, with the channel's residual noise;
* greedy batch selection: pick the candidate with the largest weighted variance reduction per
  second of tunnel time, condition the covariance on it (exact Gaussian update), repeat.

Everything is expressed in units of each channel's residual noise variance, so the six channels
add up without one dominating by its units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.errors import SettingError


@dataclass(frozen=True)
class RigRanges:
    """Where candidate runs may lie (the rig's leg and tunnel ranges) and what a run costs."""

    theta_h_min_deg: tuple[float, float] = (-50.0, 10.0)
    theta_k_max_deg: tuple[float, float] = (-80.0, -20.0)
    frequency_hz: tuple[float, float] = (0.2, 0.65)
    phi_rad: tuple[float, float] = (math.pi / 3, 5 * math.pi / 3)
    flow_speeds_mps: tuple[float, ...] = (0.0, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3)
    theta_h_max_deg: float = -100.0
    theta_k_min_deg: float = 80.0
    cycles: int = 5
    #: tunnel time per run besides its cycles: settle the flow, tare, start the logs (s)
    setup_s: float = 60.0

    def __post_init__(self):
        """The rig's ranges must make sense (checked when pipelines/plan.yaml is read, see workbench.params)."""
        for k in ("theta_h_min_deg", "theta_k_max_deg", "frequency_hz", "phi_rad"):
            lo, hi = getattr(self, k)
            if not lo <= hi:
                raise SettingError(f"{k}: lower bound {lo} above upper bound {hi}")
        if self.frequency_hz[0] <= 0 or self.cycles < 1 or not self.flow_speeds_mps or min(self.flow_speeds_mps) < 0:
            raise SettingError("frequency must be positive, cycles >= 1, flow speeds non-negative")

    @classmethod
    def from_dict(cls, doc: Mapping | None, path=None) -> "RigRanges":
        """From the ``ranges`` section of pipelines/plan.yaml, through :func:`workbench.params.build`.

        Unknown keys, wrong types and bad bounds are a :class:`~workbench.errors.ParamsError` naming
        the file, the key path and the allowed keys.
        """
        from workbench.params import build

        return build(cls, doc, key="plan.ranges", path=path)

    def run_seconds(self, frequency_hz: float, cycles: int | None = None) -> float:
        """Tunnel time of one run: its cycles plus the setup time."""
        return (self.cycles if cycles is None else cycles) / frequency_hz + self.setup_s

    def params(self, theta_h_min: float, theta_k_max: float, frequency: float, phi: float) -> dict[str, float]:
        """A run's motion parameters (contract names, rounded as a manifest writes them)."""
        return {"theta_h_min_deg": round(float(theta_h_min), 2), "theta_h_max_deg": float(self.theta_h_max_deg),
                "theta_k_min_deg": float(self.theta_k_min_deg), "theta_k_max_deg": round(float(theta_k_max), 2),
                "frequency_hz": round(float(frequency), 3), "phi_rad": round(float(phi), 4), "alpha_rad": 0.0}


@dataclass(frozen=True)
class Candidate:
    """A run the tunnel could measure."""

    params: Mapping[str, float]
    flow_speed_mps: float
    cycles: int
    reason: str = "uncertainty"
    notes: tuple[str, ...] = field(default=())


def random_candidates(ranges: RigRanges, n: int, seed: int = 0) -> list[Candidate]:
    """``n`` runs drawn within the ranges (scrambled Sobol over the motion, a flow speed each)."""
    import warnings

    from scipy.stats import qmc

    with warnings.catch_warnings():  # balance is best at powers of 2; any n is fine for a candidate pool
        warnings.simplefilter("ignore", UserWarning)
        u = qmc.Sobol(5, scramble=True, seed=seed).random(n)
    lo = np.array([ranges.theta_h_min_deg[0], ranges.theta_k_max_deg[0], ranges.frequency_hz[0], ranges.phi_rad[0]])
    hi = np.array([ranges.theta_h_min_deg[1], ranges.theta_k_max_deg[1], ranges.frequency_hz[1], ranges.phi_rad[1]])
    x = lo + u[:, :4] * (hi - lo)
    speeds = np.asarray(ranges.flow_speeds_mps, float)
    flow = speeds[np.minimum((u[:, 4] * len(speeds)).astype(int), len(speeds) - 1)]
    return [Candidate(ranges.params(*x[i]), float(flow[i]), ranges.cycles) for i in range(n)]


def candidate_motion(cands: Sequence[Candidate], dt_s: float, warmup_ticks: int, points: int):
    """Steady motions of the candidates (one row each, same length) and the ticks observed.

    Each row runs ``warmup_ticks`` plus the longest candidate cycle; the observed ticks are
    ``points`` evenly over the candidate's own last cycle.
    """
    from workbench.hydro.motion import JointSinusoid, LegMotion

    periods = np.array([1.0 / c.params["frequency_hz"] for c in cands])
    n = warmup_ticks + int(math.ceil(periods.max() / dt_s)) + 1
    t = np.arange(n) * dt_s
    rows = [JointSinusoid.from_params(c.params).evaluate(t) for c in cands]
    arr = [np.stack([r[i] for r in rows]) for i in range(6)]
    flow = np.repeat(np.array([[c.flow_speed_mps] for c in cands]), n, axis=1)
    motion = LegMotion(dt_s, arr[0], arr[1], arr[2], arr[3], flow, arr[4], arr[5])
    ticks = np.stack([np.linspace(n - 1 - p / dt_s, n - 1, points, endpoint=False).round().astype(int)
                      for p in periods])
    return motion, ticks


def _states(motion, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    m = motion
    return np.stack([a[rows, cols] for a in (m.flow_speed_mps, m.theta_h_deg, m.theta_k_deg, m.omega_h_dps,
                                            m.omega_k_dps)], axis=-1)


def _trimmed(motion, cols: np.ndarray, seq_len: int):
    """The motion from ``seq_len`` ticks before the first tick needed (a window model sees the same windows)."""
    from workbench.hydro.motion import LegMotion

    lo = max(0, int(cols.min()) - seq_len)
    if lo == 0:
        return motion, cols

    def cut(a):
        return None if a is None else a[:, lo:]

    return LegMotion(motion.dt_s, cut(motion.theta_h_deg), cut(motion.theta_k_deg), cut(motion.omega_h_dps),
                     cut(motion.omega_k_dps), cut(motion.flow_speed_mps), cut(motion.alpha_h_dps2),
                     cut(motion.alpha_k_dps2)), cols - lo


@dataclass
class Selection:
    """The greedy batch: chosen candidate indices, gains, and the region variance before and after."""

    chosen: list[int]
    gains: list[float]
    seconds: list[float]
    region_var_before: dict[str, float]
    region_var_after: dict[str, float]
    total_before: float
    total_after: float
    extra: dict = field(default_factory=dict)


class IntegratedVariance:
    """The localised ensemble covariance over region points and candidate ticks, and its greedy update."""

    def __init__(self, ensemble, region, cands: Sequence[Candidate], *, lengthscale: float = 0.5,
                 points_per_run: int = 8, dt_s: float | None = None):
        m0 = ensemble.members[0]
        self.dt_s = float(dt_s or m0.dt_s)
        self.cands = list(cands)
        self.points = int(points_per_run)
        xm, xs, _, _ = m0.norm.arrays()
        # region: member predictions at the region ticks
        rows = np.repeat(np.arange(region.ticks.shape[0]), region.ticks.shape[1])
        cols = region.ticks.ravel()
        motion, cols = _trimmed(region.motion, cols, ensemble.seq_len)
        pr = ensemble.member_predictions(motion)[:, rows, cols]                 # (K, M, 6)
        sr = _states(motion, rows, cols)
        cm, cticks = candidate_motion(self.cands, self.dt_s, ensemble.seq_len + 1, self.points)
        crow = np.repeat(np.arange(len(self.cands)), self.points)
        pc = ensemble.member_predictions(cm)[:, crow, cticks.ravel()]          # (K, N*m, 6)
        sc = _states(cm, crow, cticks.ravel())
        self.m = pr.shape[1]
        self.w = np.asarray(region.weights, float).ravel()
        preds = np.concatenate([pr, pc], axis=1)
        states = (np.concatenate([sr, sc]) - xm) / xs
        d2 = ((states[:, None, :] - states[None, :, :]) ** 2).sum(-1)
        taper = np.exp(-0.5 * d2 / lengthscale**2)
        del d2
        dev = preds - preds.mean(0)
        k = preds.shape[0]
        # noise units: the members' covariance over the channel's residual noise variance (the
        # calibration scale multiplies both alike)
        unit = 1.0 / np.maximum(ensemble.noise_var, 1e-30)
        self.cov = []
        for c in range(6):
            d = dev[:, :, c]
            self.cov.append((d.T @ d) / (k - 1) * taper * unit[c])
        self.noise_var = ensemble.noise_var
        self.scale = ensemble.scale
        # each observed tick stands for (cycles * ticks per cycle / points) readings of unit noise
        self.obs_var = np.array([self.dt_s * c.params["frequency_hz"] * self.points / c.cycles for c in self.cands])

    def region_var(self) -> np.ndarray:
        """Weighted region variance per channel (noise units)."""
        return np.array([float(self.w @ np.diag(cv)[: self.m]) for cv in self.cov])

    def _idx(self, j: int) -> np.ndarray:
        return self.m + j * self.points + np.arange(self.points)

    def gains(self, active: np.ndarray) -> np.ndarray:
        """Weighted region variance each candidate would remove (noise units, summed over channels)."""
        n = len(self.cands)
        out = np.zeros(n)
        idx = np.stack([self._idx(j) for j in range(n)])                       # (N, m)
        eye = np.eye(self.points)
        for cv in self.cov:
            kpp = cv[idx[:, :, None], idx[:, None, :]] + self.obs_var[:, None, None] * eye
            kpr = cv[idx][:, :, : self.m]                                      # (N, m, M)
            sol = np.linalg.solve(kpp + 1e-9 * eye, kpr)
            out += ((kpr * sol).sum(1) * self.w).sum(-1)
        return np.where(active, out, -np.inf)

    def condition(self, j: int) -> None:
        """Update every channel's covariance on observing candidate ``j``."""
        idx = self._idx(j)
        eye = np.eye(self.points)
        for c, cv in enumerate(self.cov):
            a = cv[np.ix_(idx, idx)] + self.obs_var[j] * eye + 1e-9 * eye
            b = cv[idx]
            self.cov[c] = cv - b.T @ np.linalg.solve(a, b)


def greedy_select(iv: IntegratedVariance, n_runs: int, ranges: RigRanges, forced: Sequence[int] = ()) -> Selection:
    """Greedy batch: the forced candidates first (diagnosis runs), then the best gain per tunnel second."""
    before = iv.region_var()
    active = np.ones(len(iv.cands), bool)
    chosen, gains, secs = [], [], []
    seconds = np.array([ranges.run_seconds(c.params["frequency_hz"], c.cycles) for c in iv.cands])
    for j in forced:
        g = iv.gains(active)[j]
        chosen.append(int(j))
        gains.append(float(g))
        secs.append(float(seconds[j]))
        active[j] = False
        iv.condition(j)
    while len(chosen) < n_runs and active.any():
        g = iv.gains(active)
        j = int(np.argmax(g / seconds))
        chosen.append(j)
        gains.append(float(g[j]))
        secs.append(float(seconds[j]))
        active[j] = False
        iv.condition(j)
    after = iv.region_var()
    # noise units back to the members' calibrated variance in physical units, per channel
    phys = iv.noise_var * iv.scale**2
    return Selection(chosen, gains, secs,
                     {c: float(v * p) for c, v, p in zip(WRENCH_CHANNELS, before, phys, strict=True)},
                     {c: float(v * p) for c, v, p in zip(WRENCH_CHANNELS, after, phys, strict=True)},
                     float(before.sum()), float(after.sum()))
