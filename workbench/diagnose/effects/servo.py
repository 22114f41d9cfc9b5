"""The servo between command and leg: a dead time then a first-order lag (``servo_lag``; docs/diagnose.md).

It acts on what the leg is commanded to do, so it is part of the physical leg handed to the simulator.
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from workbench.diagnose.effects.base import Effect, SearchParam
from workbench.diagnose.evidence import ccf_clause
from workbench.hydro.motion import LegMotion


def lag_filter(x: np.ndarray, tau_s: float, dt_s: float, axis: int = -1) -> np.ndarray:
    """First-order low-pass (time constant ``tau_s``) along ``axis``, starting at rest on the first sample.

    Exact for an input that is linear between samples (first-order hold), so the 65 Hz control
    ticks follow the continuous lag closely.
    """
    if tau_s <= 0:
        return np.array(x, float)
    e = np.exp(-dt_s / tau_s)
    g = tau_s * (1 - e) / dt_s
    b, a = np.array([1 - g, g - e]), np.array([1.0, -e])
    x = np.asarray(x, float)
    ax = axis % x.ndim
    x0 = np.take(x, [0], axis=ax)
    zi = signal.lfilter_zi(b, a).reshape([-1 if i == ax else 1 for i in range(x.ndim)]) * x0
    y, _ = signal.lfilter(b, a, x, axis=ax, zi=zi)
    return y


def dead_time(x: np.ndarray, delay_s: float, dt_s: float, axis: int = -1) -> np.ndarray:
    """``x`` delayed by ``delay_s`` along ``axis`` (4-point Lagrange fractional delay; the first sample held before).

    Accurate to about 1e-3 of the amplitude at 6 Hz on 65 Hz ticks (a linear interpolation loses
    several per cent there).
    """
    x = np.asarray(x, float)
    if delay_s <= 0:
        return np.array(x, float)
    d = delay_s / dt_s
    k = int(np.floor(d))
    u = 1.0 - (d - k)                      # the target lies u ticks after sample n - k - 1
    w = (-u * (u - 1) * (u - 2) / 6, (u + 1) * (u - 1) * (u - 2) / 2, -(u + 1) * u * (u - 2) / 2,
         (u + 1) * u * (u - 1) / 6)
    n = x.shape[axis]
    idx = np.arange(n) - k - 1
    out = np.zeros_like(x)
    for j, wj in zip((-1, 0, 1, 2), w, strict=True):
        out += wj * np.take(x, np.clip(idx + j, 0, n - 1), axis=axis)
    return out


def _number(option: str, value) -> float:
    """``value`` as a float, or a ModelError naming the servo option."""
    try:
        return float(value)
    except (TypeError, ValueError):
        from workbench.errors import ModelError

        raise ModelError(f"servo_lag: {option} must be a number, not {value!r}") from None


class ServoLag(Effect):
    """Actual joint angles = the commanded angles after a dead time and a first-order lag, both joints.

    Searched as the effective delay ``tau_s`` (dead time plus lag: the phase every harmonic sees
    at low frequency) and the share of it that is dead time. A pure first-order lag of a 60 ms
    dead time attenuates a stroke's 6 Hz harmonics to 40 %, and the force effects then take the
    misfit; a dead time with a lag fits a servo of any mix. ``shapes`` (option): ``lag`` (only a
    first-order lag, the share fixed at 0) or ``dead+lag`` (default).
    """

    name = "servo_lag"
    ranges = {"tau_s": (0.0, 0.3)}
    stage = "input"
    formula = "theta = theta_cmd(t - dead_s) / (1 + lag_s s), both joints; tau_s = dead_s + lag_s"
    TAU = SearchParam("tau_s", (0.005, 0.012, 0.02, 0.03, 0.04, 0.055, 0.075, 0.1, 0.14, 0.2), (0.0005, 0.4), log=True)
    SHARE = SearchParam("dead_share", (0.0, 0.5, 1.0), (0.0, 1.0))
    search = (TAU, SHARE)
    surrogate_ok = True
    lookahead = True
    timing = True
    #: the split of tau_s between dead time and lag locates the servo's shape, it does not measure its size
    location_params = ("dead_share", "dead_s", "lag_s")

    def __init__(self, shapes: str = "dead+lag", onset_window_s: float = 0.15, onset_min_s: float = 0.008,
                 onset_max_ratio: float = 0.5, onset_model: str = "ef"):
        for option, value, allowed in (("shapes", shapes, ("lag", "dead+lag")), ("onset_model", onset_model, ("ef", "base"))):
            if value not in allowed:
                from workbench.errors import ModelError

                raise ModelError(f"servo_lag: {option} must be {' or '.join(repr(a) for a in allowed)}, not {value!r}")
        self.shapes = shapes
        self.search = (self.TAU, self.SHARE) if shapes == "dead+lag" else (self.TAU,)
        #: the onset evidence (:meth:`seed`): half-width of the window around each run's start of motion,
        #: the least delay that seeds a branch, and how much of the window's misfit the delay must remove
        self.onset_window_s, self.onset_min_s, self.onset_max_ratio = (
            _number(k, v) for k, v in (("onset_window_s", onset_window_s), ("onset_min_s", onset_min_s),
                                       ("onset_max_ratio", onset_max_ratio)))
        #: whose start of force the onsets are compared with: ``ef`` (the empirical formula: causal and
        #: instantaneous, so its timing is right where its magnitudes are not) or ``base`` (the diagnosed model)
        self.onset_model = onset_model

    def options(self) -> dict:  # noqa: D102
        return {"shapes": self.shapes, "onset_window_s": self.onset_window_s, "onset_min_s": self.onset_min_s,
                "onset_max_ratio": self.onset_max_ratio, "onset_model": self.onset_model}

    def _onset_model(self, problem):
        """The model whose start of force the onsets are compared with (None: the problem's own)."""
        if self.onset_model == "base":
            return None
        from workbench.hydro.legmodel import load_leg_model

        ef = load_leg_model("ef")
        return None if type(problem.model) is type(ef) else ef

    def seed(self, problem, config=None) -> tuple[dict, str] | None:
        """The delay between the commanded start of motion and the measured force's, from the rest-to-motion onsets.

        At the first tick of a run the leg starts from rest: any causal model of the force, however
        wrong its magnitudes, predicts the force to change from that tick on, and a servo's delay
        moves the measured change later. The model's prediction shifted by each trial delay (with a
        free gain and offset per run and channel, so a wrong added mass or drag does not count) is
        compared with the reading within ``onset_window_s`` of the onset. A seed when the best delay
        is at least ``onset_min_s`` and removes more than ``1 - onset_max_ratio`` of the window's
        misfit at zero delay (on the clean rich tunnel the best shift is -2 ms and removes 27 %; planted
        delays 98-99 %). Training runs with a rest stretch only; None without them. The onsets are compared with the
        EF's by default (``onset_model``): a learned model's own start of force may be late or early
        (the demo's FED-LSTM starts 38 ms late on the clean rich tunnel, where the EF is within 2 ms).
        ``config``: the configuration the selection's paths ended with; its input and filter effects (a
        mount mode also starts the force late) act on the compared prediction, so a delay they already
        explain seeds nothing.
        """
        timing = None
        if config is not None:  # what the paths already claimed that moves or filters the force in time
            from workbench.diagnose.chain import Configuration

            timing = Configuration(config.stage("input") + config.stage("filter"))
        found = onset_delay(problem, self.onset_window_s, model=self._onset_model(problem), config=timing)
        if found is None:
            return None
        delay, ratio, runs = found
        if delay < self.onset_min_s or ratio > self.onset_max_ratio:
            return None
        nl = {"tau_s": delay, "dead_share": 1.0} if self.shapes == "dead+lag" else {"tau_s": delay}
        return nl, (f"the force starts {1000 * delay:.0f} ms after the command in {runs} runs' onsets "
                    f"(misfit within {self.onset_window_s:g} s of the onset {ratio:.0%} of that at no delay)")

    @staticmethod
    def split(nl: dict) -> tuple[float, float]:
        """(dead time, lag) in seconds from the searched values (a saved ``{"tau_s": x}`` is a pure lag)."""
        tau = float(nl["tau_s"])
        share = float(np.clip(nl.get("dead_share", 0.0), 0.0, 1.0))
        return tau * share, tau * (1.0 - share)

    def canonical_params(self, coefs, nl, cov, local=None):  # noqa: D102
        params, se = super().canonical_params(coefs, nl, cov, local)
        if "tau_s" in nl:
            params["dead_s"], params["lag_s"] = self.split(nl)
        return params, se

    def on_output(self, w: np.ndarray, dt_s: float, nl: dict) -> np.ndarray:
        """A causal model's output through the same dead time and lag (first order in tau)."""
        dead, lag = self.split(nl)
        return lag_filter(dead_time(w, dead, dt_s, axis=-2), lag, dt_s, axis=-2)

    def hint(self, ev, params: dict) -> str:  # noqa: D102
        return ccf_clause(ev, "model_force_rate", "the rate of the model's force")

    def transform_motion(self, motion: LegMotion, nl: dict) -> LegMotion:  # noqa: D102
        dead, tau = self.split(nl)
        dt = motion.dt_s
        if tau <= 0 and dead <= 0:
            return motion
        # angles, rates and accelerations through the same (linear) delay and lag: the lag of a
        # derivative is the derivative of the lag, and filtering each keeps the 65 Hz error at 1e-4
        ah, ak = motion.accelerations_dps2()
        f = (lambda a: lag_filter(dead_time(a, dead, dt), tau, dt))  # noqa: E731
        return LegMotion(dt, f(motion.theta_h_deg), f(motion.theta_k_deg), f(motion.omega_h_dps),
                         f(motion.omega_k_dps), motion.flow_speed_mps, f(ah), f(ak))


def onset_delay(problem, window_s: float = 0.15, max_s: float = 0.2, step_s: float = 0.002, model=None,
                config=None):
    """Delay of the measured wrench behind the base model's around each training run's start of motion.

    For each trial delay d (``-0.05`` s to ``max_s``), every run with a rest stretch before its motion
    and every channel: the reading within ``window_s`` of the first moving tick against the model's
    prediction shifted by d, with a gain and an offset fitted (least squares), the misfit scaled by
    the channel's variance at rest. Returns ``(delay_s, ratio, runs)``: the best delay, the summed
    misfit there over that at zero delay, the runs used; None when no run has a rest stretch.
    ``model``: whose prediction the readings are compared with (None: the problem's base model), under
    ``config`` (None: alone; force-stage effects in it add nothing, their coefficients are not passed).
    """
    from workbench.diagnose.chain import Configuration, build_design

    config = Configuration() if config is None else config
    grid = np.arange(-0.05, max_s + 0.5 * step_s, step_s)
    sse = np.zeros(len(grid))
    runs = 0
    for rs in problem.campaign.train_sets:
        if model is None:
            pred = problem.design(rs, config, {}).predict({})
        else:
            pred = build_design(model, rs, config, {}, problem.lowpass, problem.geometry).predict({})
        for b in range(rs.y.shape[0]):
            t, v = rs.time_s[b], rs.valid[b]
            quiet = v & (t < -window_s)
            w = v & (np.abs(t) <= window_s)
            if quiet.sum() < 8 or w.sum() < 8:
                continue
            runs += 1
            tw, tv = t[w], t[v]
            shifted_t = (tw[None, :] - grid[:, None]).ravel()
            for c in range(rs.y.shape[2]):
                noise = float(np.var(rs.y[b, quiet, c]))
                if noise <= 0:
                    continue
                y = rs.y[b, w, c] - rs.y[b, w, c].mean()
                p = np.interp(shifted_t, tv, pred[b, v, c]).reshape(len(grid), -1)
                p = p - p.mean(axis=1, keepdims=True)
                pp = np.einsum("dn,dn->d", p, p)
                py = p @ y
                explained = np.divide(py * py, pp, out=np.zeros_like(pp), where=pp > 0)
                sse += (y @ y - explained) / noise
    if runs == 0:
        return None
    k = int(np.argmin(sse))
    zero = sse[int(np.argmin(np.abs(grid)))]
    return float(grid[k]), float(sse[k] / zero) if zero > 0 else 1.0, runs


LIBRARY_RANK = 1  # place in the library's order (workbench.diagnose.library._in_tree)

EFFECTS = (ServoLag,)
