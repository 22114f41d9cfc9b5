"""Weighted least squares on block sums: fits, held-out errors and robust covariances without the big matrix.

Per block of ticks and per channel the design is reduced to its Gram matrix ``G = X'X``,
``b = X'r`` and ``yy = r'r`` (r = reading - fixed part). Every fit, held-out error and
significance test of the selection is then small-matrix algebra on these sums. Channels are
weighted by ``w_c`` (the inverse of the diagnosed model's residual variance: each channel counts
alike). Per-run columns (a tone whose phase differs run to run) are profiled out run by run.
Parameter covariances are sandwich (HAC) estimates over blocks, with Newey-West weights between
neighbouring blocks of a run, so autocorrelated residuals do not shrink the intervals.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Grams:
    """Block sums of one configuration over all runs (training and held-out)."""

    names: list[str]
    chan_cols: list[np.ndarray]   # per channel: indices into ``names`` of the columns it holds
    G: list[np.ndarray]           # per channel: (nb, k_c + m, k_c + m)
    b: list[np.ndarray]           # per channel: (nb, k_c + m)
    yy: np.ndarray                # (nb, 6)
    n: np.ndarray                 # (nb,) ticks per block
    run: np.ndarray               # (nb,) campaign run index
    order: np.ndarray             # (nb,) block number within the run
    heldout: np.ndarray           # (nb,) bool
    local_names: list[str]
    #: Gaussian priors (mean, sd) of shared columns by name (``Problem.grams`` fills it from the effects)
    prior: dict | None = None

    @property
    def n_local(self) -> int:
        """Per-run columns."""
        return len(self.local_names)

    def subset(self, names: list[str]) -> "Grams":
        """The same sums for a subset of the shared columns (local columns kept)."""
        pos = {n: i for i, n in enumerate(self.names)}
        keep = [pos[n] for n in names]
        newpos = {old: new for new, old in enumerate(keep)}
        m = self.n_local
        cc, gg, bb = [], [], []
        for c in range(6):
            sel = [k for k, col in enumerate(self.chan_cols[c]) if col in newpos]
            k_c = len(self.chan_cols[c])
            idx = np.array(sel + list(range(k_c, k_c + m)), int)
            cc.append(np.array([newpos[self.chan_cols[c][k]] for k in sel], int))
            gg.append(self.G[c][:, idx][:, :, idx])
            bb.append(self.b[c][:, idx])
        return Grams(list(names), cc, gg, bb, self.yy, self.n, self.run, self.order, self.heldout,
                     self.local_names, {k: v for k, v in (self.prior or {}).items() if k in pos and k in names} or None)


def accumulate(design, rs, blocks, shared_names: list[str] | None = None) -> Grams:
    """Block sums of ``design`` on the batch ``rs`` (ticks gathered by ``blocks``)."""
    b_, t_ = rs.shape
    names = design.names if shared_names is None else shared_names
    pos = {n: i for i, n in enumerate(design.names)}
    compare = getattr(design, "compare", None)
    resid = rs.y - design.base
    if getattr(design, "fit_offset", None) is not None:  # a known part the fit takes off, not predicted apart
        resid = resid - design.fit_offset
    if compare is not None:  # an equation-error filter effect: residual and columns through its inverse
        resid = compare(resid)
    resid = resid.reshape(b_ * t_, 6)
    ticks = blocks.ticks
    pad = ticks < 0
    idx = np.where(pad, 0, ticks)
    wmask = (~pad).astype(float)[..., None]
    r = resid[idx] * wmask                     # (nb, L, 6)
    yy = np.einsum("nlc,nlc->nc", r, r)
    local = design.local if compare is None or not design.local else _compared(
        design.local, design.local_names, getattr(design, "compared_local", {}), compare)
    loc = [c.reshape(b_ * t_, 6)[idx] * wmask for c in local]  # each (nb, L, 6)
    # every shared column gathered once for all channels (a gather per channel and column costs
    # six times as much), as (nb, L, 6, k)
    used = [i for i, n in enumerate(names) if n in pos]
    if used:
        # gather the analysis ticks first (a strided subset), then stack the smaller arrays
        src = [design.cols[pos[names[i]]] for i in used]
        if compare is not None:
            src = _compared(src, [names[i] for i in used], getattr(design, "compared", {}), compare)
        gathered = np.stack([c.reshape(b_ * t_, 6)[idx] for c in src], axis=-1)
        gathered *= wmask[..., None]
    col_of = {i: j for j, i in enumerate(used)}
    chan_cols, G, bvec = [], [], []
    for c in range(6):
        cols = [i for i in used if design.support[pos[names[i]]][c]]
        parts = []
        if cols:
            parts.append(gathered[:, :, c, [col_of[i] for i in cols]])
        if loc:
            parts.append(np.stack([lc[..., c] for lc in loc], axis=-1))
        if parts:
            x = np.concatenate(parts, axis=-1) if len(parts) > 1 else parts[0]   # (nb, L, k)
            G.append(np.matmul(np.swapaxes(x, 1, 2), x))
            bvec.append(np.einsum("nlk,nl->nk", x, r[..., c]))
        else:
            G.append(np.zeros((len(ticks), 0, 0)))
            bvec.append(np.zeros((len(ticks), 0)))
        chan_cols.append(np.array(cols, int))
    return Grams(list(names), chan_cols, G, bvec, yy, (~pad).sum(axis=1), blocks.run, blocks.order,
                 np.full(len(ticks), rs.heldout), list(design.local_names))


def _compared(cols: list[np.ndarray], names: list[str], done: dict[str, np.ndarray], compare) -> list[np.ndarray]:
    """``cols`` through ``compare``, taking those the design has already compared (``done``, by name)."""
    todo = [i for i, n in enumerate(names) if n not in done]
    out = [done.get(n) for n in names]
    if todo:
        for i, c in zip(todo, compare(np.stack([cols[i] for i in todo])), strict=True):
            out[i] = c
    return out


def concat(parts: list[Grams]) -> Grams:
    """Join the sums of several batches (same columns)."""
    p0 = parts[0]
    return Grams(p0.names, p0.chan_cols, [np.concatenate([p.G[c] for p in parts]) for c in range(6)],
                 [np.concatenate([p.b[c] for p in parts]) for c in range(6)],
                 np.concatenate([p.yy for p in parts]), np.concatenate([p.n for p in parts]),
                 np.concatenate([p.run for p in parts]), np.concatenate([p.order for p in parts]),
                 np.concatenate([p.heldout for p in parts]), p0.local_names, p0.prior)


def weighted(gr: Grams, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Channel-weighted sums per block: G (nb, K+m, K+m), b (nb, K+m), yy (nb,)."""
    k, m = len(gr.names), gr.n_local
    nb = len(gr.yy)
    gw = np.zeros((nb, k + m, k + m))
    bw = np.zeros((nb, k + m))
    for c in range(6):
        idx = np.concatenate([gr.chan_cols[c], np.arange(k, k + m)]).astype(int)
        if len(idx) == 0:
            continue
        gw[:, idx[:, None], idx[None, :]] += w[c] * gr.G[c]
        bw[:, idx] += w[c] * gr.b[c]
    return gw, bw, gr.yy @ w


@dataclass(frozen=True)
class FixedPoint:
    """How a fit's fixed-point passes ended (crosstalk columns read the prediction the force coefficients set).

    ``step_se``: the last pass's largest coefficient move in that coefficient's standard errors,
    ``worst`` its name. The fit settled when the relative change fell under the tolerance, or
    when the last move is a small share of the coefficients' own uncertainty (``STEP_SE``): more
    passes would not change what the fit says.
    """

    passes: int
    change: float
    step_se: float
    worst: str
    settled: bool

    #: the passes stop when the largest relative change falls under this (``Problem.fit``)
    RELATIVE = 1e-3
    #: a last move under this many standard errors counts as settled
    STEP_SE = 0.1

    def note(self) -> str:
        """One sentence for a record or a report."""
        return (f"the fit's fixed point was not reached after {self.passes} passes: the last pass moved {self.worst} "
                f"by {self.step_se:.2g} standard errors (relative change {self.change:.2g})")


@dataclass
class Fit:
    """A weighted least-squares fit of shared (and per-run) coefficients."""

    names: list[str]
    theta: np.ndarray                 # (K,) shared
    local: dict[int, np.ndarray]      # run index -> (m,) per-run coefficients
    local_info: dict[int, np.ndarray]  # run index -> (m,) diagonal of the per-run information
    cov: np.ndarray                   # (K, K) HAC covariance of theta
    sse_block: np.ndarray             # (nb,) weighted SSE per block
    sse_block_c: np.ndarray           # (nb, 6) SSE per block and channel (unweighted)
    #: how the fixed-point passes of :meth:`~workbench.diagnose.problem.Problem.fit` ended (None: one linear solve)
    fixed_point: FixedPoint | None = None

    def coefs(self) -> dict[str, float]:
        """Shared coefficients by name."""
        return {n: float(v) for n, v in zip(self.names, self.theta, strict=False)}

    def stderr(self) -> dict[str, float]:
        """Standard errors by name."""
        return {n: float(np.sqrt(max(self.cov[i, i], 0.0))) for i, n in enumerate(self.names)}


def _solve(a: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Solve a symmetric system robustly (Jacobi-scaled, pseudo-inverse on rank loss)."""
    if a.shape[0] == 0:
        return np.zeros(0)
    d = np.sqrt(np.maximum(np.diag(a), 1e-300))
    s = a / d[:, None] / d[None, :]
    try:
        x = np.linalg.solve(s + 1e-12 * np.eye(len(d)), r / d)
    except np.linalg.LinAlgError:
        x = np.linalg.pinv(s, rcond=1e-10) @ (r / d)
    return x / d


def _inv(a: np.ndarray) -> np.ndarray:
    if a.shape[0] == 0:
        return np.zeros((0, 0))
    d = np.sqrt(np.maximum(np.diag(a), 1e-300))
    s = a / d[:, None] / d[None, :]
    return np.linalg.pinv(s, rcond=1e-12) / d[:, None] / d[None, :]


def fit(gr: Grams, w: np.ndarray, hac_lags: int = 2, fixed: dict[str, float] | None = None) -> Fit:
    """Fit on the training blocks; per-run columns of held-out runs are fitted on those runs.

    ``fixed`` pins some shared coefficients (they are not fitted).
    """
    k, m = len(gr.names), gr.n_local
    gw, bw, yyw = weighted(gr, w)
    fixed = fixed or {}
    free = np.array([n not in fixed for n in gr.names], bool)
    theta_fixed = np.array([fixed.get(n, 0.0) for n in gr.names])
    # move the fixed coefficients into the right-hand side
    b_adj = bw - np.einsum("nij,j->ni", gw[:, :, :k], theta_fixed)
    train = ~gr.heldout
    sums = _run_sums(gr, gw, b_adj)
    fi = np.flatnonzero(free)
    a_s, r_s, cinv = _profiled_system(sums, fi, k, m)
    theta = theta_fixed.copy()
    theta[fi] = _solve(a_s, r_s)
    local, local_info, th_block = _per_run_coefs(gr, sums, cinv, fi, k, m, theta)
    prior = {n: v for n, v in (gr.prior or {}).items() if n in gr.names and n not in fixed}
    cov_prior = None
    if prior:
        # a Gaussian prior on some coefficients, combined with the data's robust (sandwich)
        # likelihood: posterior precision = C^-1 + D, mean = (C^-1 theta + D mu) / that
        cov_data = _robust_cov(gr, fi, a_s, bw, gw, th_block, train, hac_lags)
        theta, cov_prior = _posterior(theta, fi, cov_data, prior, list(gr.names))
        local, local_info, th_block = _per_run_coefs(gr, sums, cinv, fi, k, m, theta)
    sse = yyw - 2 * np.einsum("ni,ni->n", th_block, bw) + np.einsum("ni,nij,nj->n", th_block, gw, th_block)
    sse_c = _sse_by_channel(gr, th_block, k, m)
    cov_f = cov_prior if cov_prior is not None else _robust_cov(gr, fi, a_s, bw, gw, th_block, train, hac_lags)
    cov = np.full((k, k), 0.0)
    cov[np.ix_(fi, fi)] = cov_f
    return Fit(list(gr.names), theta, local, local_info, cov, np.maximum(sse, 0.0), np.maximum(sse_c, 0.0))


@dataclass
class _RunSums:
    """Weighted block sums added up per run (the fit's unit for per-run columns)."""

    runs: np.ndarray       # (nr,) campaign run indices, sorted
    g: np.ndarray          # (nr, K+m, K+m)
    b: np.ndarray          # (nr, K+m), the fixed coefficients already moved to this side
    held: np.ndarray       # (nr,) bool: a held-out run


def _run_sums(gr: Grams, gw: np.ndarray, b_adj: np.ndarray) -> _RunSums:
    """The weighted sums of every block added into its run's."""
    runs = np.unique(gr.run)
    run_pos = {r: i for i, r in enumerate(runs)}
    ridx = np.array([run_pos[r] for r in gr.run])
    nr = len(runs)
    g_run = np.zeros((nr,) + gw.shape[1:])
    b_run = np.zeros((nr,) + b_adj.shape[1:])
    # np.add.at's sums in its order (so to the bit), 3-12x faster: a block is a few hundred numbers
    for i, r in enumerate(ridx.tolist()):
        g_run[r] += gw[i]
        b_run[r] += b_adj[i]
    held_run = np.zeros(nr, bool)
    held_run[ridx[gr.heldout]] = True
    return _RunSums(runs, g_run, b_run, held_run)


def _profiled_system(sums: _RunSums, fi: np.ndarray, k: int, m: int) -> tuple[np.ndarray, np.ndarray, dict]:
    """Normal equations of the free shared coefficients over the training runs, per-run columns profiled out.

    Returns the matrix, the right-hand side and, per run, the inverse of its per-run block (empty without
    per-run columns).
    """
    a_s = np.zeros((len(fi), len(fi)))
    r_s = np.zeros(len(fi))
    cinv = {}
    for i in range(len(sums.runs)):
        A = sums.g[i][np.ix_(fi, fi)]
        a = sums.b[i][fi]
        if m:
            B = sums.g[i][np.ix_(fi, np.arange(k, k + m))]
            C = sums.g[i][k:, k:]
            ci = _inv(C)
            cinv[i] = ci
            A = A - B @ ci @ B.T
            a = a - B @ ci @ sums.b[i][k:]
        if not sums.held[i]:
            a_s += A
            r_s += a
    return a_s, r_s, cinv


def _per_run_coefs(gr: Grams, sums: _RunSums, cinv: dict, fi: np.ndarray, k: int, m: int, theta: np.ndarray):
    """Per-run coefficients given the shared ``theta``, their information, and every block's coefficient row."""
    local, local_info = {}, {}
    if m:
        for i in range(len(sums.runs)):
            C = sums.g[i][k:, k:]
            rhs = sums.b[i][k:] - sums.g[i][k:, fi] @ theta[fi]
            local[int(sums.runs[i])] = cinv[i] @ rhs
            local_info[int(sums.runs[i])] = np.diag(C).copy()
    th_block = np.zeros((len(gr.run), k + m))
    th_block[:, :k] = theta
    if m:
        th_block[:, k:] = np.array([local[int(r)] for r in gr.run])
    return local, local_info, th_block


def _sse_by_channel(gr: Grams, th_block: np.ndarray, k: int, m: int) -> np.ndarray:
    """Unweighted SSE per block and channel of the coefficient rows ``th_block``."""
    sse_c = np.zeros_like(gr.yy)
    for c in range(6):
        idx = np.concatenate([gr.chan_cols[c], np.arange(k, k + m)]).astype(int)
        if len(idx) == 0:
            sse_c[:, c] = gr.yy[:, c]
            continue
        tc = th_block[:, idx]
        sse_c[:, c] = (gr.yy[:, c] - 2 * np.einsum("ni,ni->n", tc, gr.b[c])
                       + np.einsum("ni,nij,nj->n", tc, gr.G[c], tc))
    return sse_c


def _robust_cov(gr: Grams, fi, a_s, bw, gw, th_block, train, hac_lags: int) -> np.ndarray:
    """Sandwich covariance of the free shared coefficients over the training blocks."""
    scores = bw[:, fi] - np.einsum("nij,nj->ni", gw[:, fi, :], th_block)
    n_runs = len(np.unique(gr.run[train]))
    if n_runs >= len(fi) + 5:
        # clusters = runs: a misfit that persists through a run (a clock offset, a per-run bias)
        # correlates all its blocks, which a few Newey-West lags would miss
        rs = gr.run[train]
        u, inv = np.unique(rs, return_inverse=True)
        per_run = np.zeros((len(u), len(fi)))
        np.add.at(per_run, inv, scores[train])
        return _hac_cov(a_s, per_run, u, np.zeros(len(u), int), 0)
    return _hac_cov(a_s, scores[train], gr.run[train], gr.order[train], hac_lags)


def _posterior(theta: np.ndarray, fi: np.ndarray, cov_data: np.ndarray, prior: dict, names: list[str]):
    """Gaussian prior (mean, sd) on some free coefficients and the data's estimate ``theta`` with covariance ``cov_data``.

    Returns the posterior mean (all coefficients: correlated ones move too) and covariance of the free ones.
    """
    pos = {names[j]: i for i, j in enumerate(fi)}
    prec = _inv(cov_data)
    d = np.zeros(len(fi))
    mu = np.zeros(len(fi))
    for n, (mean, sd) in prior.items():
        if n in pos and sd > 0:
            d[pos[n]] = 1.0 / sd ** 2
            mu[pos[n]] = mean
    post_cov = _inv(prec + np.diag(d))
    out = theta.copy()
    out[fi] = post_cov @ (prec @ theta[fi] + d * mu)
    return out, post_cov


def _hac_cov(bread_inv: np.ndarray, scores: np.ndarray, run: np.ndarray, order: np.ndarray, lags: int) -> np.ndarray:
    """Newey-West sandwich: A^-1 (sum s s' + weighted neighbour terms within runs) A^-1."""
    if bread_inv.shape[0] == 0:
        return np.zeros((0, 0))
    meat = scores.T @ scores
    key = run.astype(np.int64) * 1_000_000 + order
    srt = np.argsort(key)
    s, r, o = scores[srt], run[srt], order[srt]
    for lag in range(1, lags + 1):
        wl = 1.0 - lag / (lags + 1)
        same = (r[lag:] == r[:-lag]) & (o[lag:] - o[:-lag] == lag)
        if same.any():
            c = s[lag:][same].T @ s[:-lag][same]
            meat += wl * (c + c.T)
    ai = _inv(bread_inv)
    # small-sample correction of the cluster sandwich: blocks / (blocks - parameters)
    n, k = scores.shape
    scale = n / (n - k) if n > k + 1 else float(n)
    return ai @ meat @ ai * scale
