"""Nonlinear parameters of one effect: a grid search and a local refinement that wrap the linear fit.

:func:`search` minimises the training SSE over an effect's searched parameters (a lag's time
constant, a tone's frequency), the linear terms refitted at every value: a grid (or a warm start)
then a bounded 1-D search or Nelder-Mead in (log) coordinates. :func:`parabola` finishes a
parameter with three fits of an expensive model; :func:`snap` and :func:`around` are the grids
they search on.
"""

from __future__ import annotations

from itertools import product

import numpy as np
from scipy import optimize

from workbench.diagnose import lsq
from workbench.diagnose.chain import Active, Configuration
from workbench.diagnose.effects.base import Effect
from workbench.diagnose.selection_records import SelectionSettings


def search(s: SelectionSettings, problem, config: Configuration, coefs: dict, names: list[str], effect: Effect,
           grids: dict[str, tuple] | None = None, start: dict | None = None, fast: bool = True) -> tuple[dict, dict]:
    """Nonlinear parameters of ``effect`` minimising the training SSE (linear terms refitted each time).

    ``fast``: through the effect's own faster criterion where it has one (:meth:`Effect.search_grams`,
    for screening candidates); False: through the whole design (the reported values' final refinement).
    """
    params = effect.search
    pnames = [p.name for p in params]
    w = problem.weights
    hac = problem.settings.hac_lags
    cache: dict[tuple, float] = {}
    extra = [f"{effect.name}.{n}" for n in effect.linear_names()]
    quick = effect.search_grams(problem, config, coefs, names + extra) if fast else None
    if fast and quick is None:
        quick = _beside_filters(problem, config, coefs, names + extra, effect)

    def objective(values) -> float:
        key = tuple(round(float(v), 10) for v in values)
        if key not in cache:
            nl = dict(zip(pnames, key, strict=False))
            if quick is not None:
                gr = quick(nl)
            else:
                gr = problem.grams(config.with_effect(Active(effect, nl)), coefs, names + extra, sets="search")
            cache[key] = float(lsq.fit(gr, w, hac).sse_block.sum())
        return cache[key]

    warm = start is not None and grids is None
    if warm:
        best = [start[p] for p in pnames]
    else:
        axes = [grids[p.name] if grids and p.name in grids else p.grid for p in params]
        points = list(product(*axes))
        vals = [objective(pt) for pt in points]
        best = list(points[int(np.argmin(vals))])
    out, unfinished = _refine_locally(s, objective, params, best, grids, warm)
    if objective(out) > objective(best):
        out = best
    profile = {"params": pnames, "points": [list(k) for k in cache], "sse": list(cache.values()),
               "converged": unfinished is None, "note": unfinished}
    return effect.searched(dict(zip(pnames, out, strict=False)), problem, config, coefs, names), profile


def _beside_filters(problem, config: Configuration, coefs: dict, names: list[str], effect: Effect):
    """A candidate's faster criterion beside claimed filter effects that offer one (:meth:`Effect.search_reading`).

    The reading mapped once per batch (through each filter's map, last filter first) is compared
    with the design of ``config`` without its filters plus the candidate: an evaluation then
    filters nothing (a mode claimed: the force terms through the mode and back at every new
    value). None when ``config`` has no filter, a filter offers no map, or a sensor effect is in
    ``config`` or searched (its columns read the prediction through the filters).
    """
    filters = config.stage("filter")
    if not filters or config.stage("sensor") or effect.stage in ("filter", "sensor"):
        return None
    shift = {}
    for rs, _blocks in problem.sets("search"):
        mapped = rs.y
        for a in reversed(filters):
            f = a.effect.search_reading(a.nl, rs.dt_s)
            if f is None:
                return None
            mapped = f(mapped)
        shift[id(rs)] = mapped - rs.y
    reduced = Configuration([a for a in config.actives if a.effect.stage != "filter"])

    def grams(nl: dict):
        return problem.grams(reduced.with_effect(Active(effect, nl)), coefs, names, sets="search", shift=shift)

    return grams


def _refine_locally(s: SelectionSettings, objective, params, best: list, grids: dict | None,
                    warm: bool) -> tuple[list[float], str | None]:
    """Local refinement from ``best`` in (log) coordinates, clipped to the bounds: bounded 1-D search or Nelder-Mead.

    Returns the values and None when the search converged, else a sentence saying why it did not:
    the 1-D search ran out of evaluations, or its best value sits at its window's edge inside the
    parameter's bounds (the optimum lies outside the window); Nelder-Mead's simplex still spans
    more than ``SIMPLEX_SPAN`` in (log) coordinates when its evaluations run out (its ``fatol`` is
    never met on an SSE, so its own success flag says nothing).
    """
    pnames = [p.name for p in params]
    logs = [p.log for p in params]
    lo = np.array([np.log(p.bounds[0]) if p.log else p.bounds[0] for p in params])
    hi = np.array([np.log(p.bounds[1]) if p.log else p.bounds[1] for p in params])

    def to_x(v):
        return np.array([np.log(max(x, 1e-300)) if lg else x for x, lg in zip(v, logs, strict=False)])

    def from_x(x):
        x = np.clip(x, lo, hi)
        return [float(np.exp(v)) if lg else float(v) for v, lg in zip(x, logs, strict=False)]

    x0 = to_x(best)
    if len(params) == 1:
        step = 0.25 if logs[0] else max(0.02 * abs(x0[0]), 0.01)
        if warm:
            step = s.warm_window if logs[0] else max(0.2 * abs(x0[0]), 0.05)
        if grids and pnames[0] in grids and len(grids[pnames[0]]) > 1:
            step = float(np.diff(grids[pnames[0]]).mean())
        window = (max(lo[0], x0[0] - step), min(hi[0], x0[0] + step))
        xatol = 0.005 if logs[0] else 5e-4
        res = optimize.minimize_scalar(lambda x: objective(from_x(np.array([x]))), bounds=window, method="bounded",
                                       options={"xatol": xatol, "maxiter": s.refine_evals})
        out = from_x(np.array([res.x]))
        edge = [w for w, b in zip(window, (lo[0], hi[0]), strict=True) if abs(res.x - w) < 2 * xatol and abs(w - b) > 1e-12]
        if edge:
            return out, f"{pnames[0]}: its best value lies at the edge of its search window (the optimum is beyond it)"
        if not res.success:
            return out, f"{pnames[0]}: the 1-D search ran out of its {s.refine_evals} evaluations"
        return out, None
    return _nelder_mead(s, objective, pnames, logs, x0, lo, hi, from_x)


#: a Nelder-Mead simplex narrower than this in (log) coordinates has converged (1 % of a log-scaled value)
SIMPLEX_SPAN = 0.01


def _nelder_mead(s: SelectionSettings, objective, pnames: list[str], logs: list[bool], x0: np.ndarray,
                 lo: np.ndarray, hi: np.ndarray, from_x) -> tuple[list[float], str | None]:
    """:func:`_refine_locally`'s Nelder-Mead for two or more parameters, in (log) coordinates.

    The simplex stays inside the bounds (scipy clips every trial point): outside them the clipped
    objective is flat, and a simplex let out there wandered until its evaluations ran out (measured: 17
    of 24 searches of a servo case, a dead-time share held at 0 or 1). It stops once it spans under a
    third of ``SIMPLEX_SPAN`` (an SSE never meets a ``fatol``, so that test is off).
    """
    x0 = np.clip(x0, lo, hi)
    simplex = [x0]
    for i in range(len(x0)):
        step = 0.3 if logs[i] else 0.1 * max(abs(x0[i]), 0.5)
        if x0[i] + step > hi[i]:
            step = -step
        simplex.append(x0 + np.eye(len(x0))[i] * step)
    maxfev = s.refine_evals * len(x0) * 2
    res = optimize.minimize(lambda x: objective(from_x(x)), x0, method="Nelder-Mead",
                            bounds=list(zip(lo, hi, strict=True)),
                            options={"initial_simplex": np.clip(np.array(simplex), lo, hi), "maxfev": maxfev,
                                     "xatol": SIMPLEX_SPAN / 3, "fatol": np.inf})
    sim = np.clip(res.final_simplex[0], lo, hi)
    span = float(np.max(np.abs(sim - sim[0]))) if len(sim) else 0.0
    if span > SIMPLEX_SPAN:
        return from_x(res.x), (f"{', '.join(pnames)}: Nelder-Mead's simplex still spans {span:.2g} (log) units after "
                               f"its {maxfev} evaluations")
    return from_x(res.x), None


def parabola(problem, config, coefs, names, effect, start: dict) -> dict:
    """The first searched parameter finished by a parabola through three values around ``start`` (others kept).

    Log-scaled parameters (a lag) at start x exp(-0.12, 0, 0.12); others at start -+ 0.03.
    """
    p = effect.search[0]
    extra = [f"{effect.name}.{n}" for n in effect.linear_names()]

    def objective(v: float) -> float:
        cfg = config.with_effect(Active(effect, {**start, p.name: v}))
        gr = problem.grams(cfg, coefs, names + extra, sets="search")
        return float(lsq.fit(gr, problem.weights, problem.settings.hac_lags).sse_block.sum())

    v0 = float(start[p.name])
    if p.log and v0 <= 0:
        return start
    width = 0.12 if p.log else 0.03
    x0 = np.log(v0) if p.log else v0
    xs = x0 + np.array([-width, 0.0, width])

    def value(x: float) -> float:
        return float(np.clip(np.exp(x) if p.log else x, *p.bounds))

    ys = np.array([objective(value(x)) for x in xs])
    best = value(xs[int(np.argmin(ys))])
    vx = _parabola_min(xs, ys)
    if vx is not None and abs(vx - x0) <= 2 * width:
        v = value(vx)
        if objective(v) < ys.min():
            best = v
    return {**start, p.name: best}


def around(effect: Effect, nl: dict) -> dict[str, tuple]:
    """A small grid around an effect's searched values: each value and its neighbours on the effect's own grid."""
    out = {}
    for p in effect.search:
        v = float(nl.get(p.name, np.median(p.grid)))
        grid = sorted({*p.grid, v})
        i = grid.index(v)
        out[p.name] = tuple(grid[max(i - 1, 0): i + 2])
    return out


def snap(v: float, p) -> float:
    """A searched value on a coarse grid (2 % steps in log, 0.005 otherwise), inside its bounds."""
    if p.log and v > 0:
        v = float(np.exp(np.round(np.log(v) / 0.02) * 0.02))
    else:
        v = float(np.round(v / 0.005) * 0.005)
    return float(np.clip(v, *p.bounds))


def _parabola_min(x: np.ndarray, y: np.ndarray) -> float | None:
    """Vertex of the parabola through three points (None when it opens downwards)."""
    a, b, _ = np.polyfit(x, y, 2)
    return float(-b / (2 * a)) if a > 0 else None
