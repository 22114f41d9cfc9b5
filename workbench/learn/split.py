"""Train/validation/test split by motion-parameter set, never by window.

Overlapping windows of one run, and runs of one parameter set at other flow speeds, are nearly
the same data: splitting them apart would leak the test set into training. So the unit of the
split is the parameter set (the run's motion parameters): every run of a set, at every flow
speed, measured or interpolated, lands in the same split. The assignment depends only on the
seed and the sorted set keys, so the same campaign splits the same way whatever the row order,
and it is recorded (JSON) with the model and read back by ``workbench evaluate``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from workbench.errors import ContractError, DataError
from workbench.learn.windows import PARAM_DECIMALS, RunTable, set_key, set_label

SPLITS = ("train", "val", "test")
SCHEMA = "workbench/learn-split@1"


@dataclass(frozen=True)
class ParameterSplit:
    """Which split each parameter set belongs to."""

    seed: int
    fractions: tuple[float, float, float]
    param_columns: tuple[str, ...]
    #: set key -> "train" | "val" | "test"
    assignment: Mapping[tuple, str]
    #: set key -> parameter values (contract names)
    params: Mapping[tuple, Mapping[str, float]]
    pin_test: tuple[Mapping[str, float], ...] = field(default=())
    #: parameters whose values form strata; val and test take each stratum's share (empty: plain draw)
    stratify: tuple[str, ...] = field(default=())

    def split_of(self, params: Mapping[str, float]) -> str | None:
        """The split of a parameter set (None when the set is unknown to this split)."""
        try:
            return self.assignment.get(set_key(params, self.param_columns))
        except KeyError:
            return None

    def sets(self, name: str) -> list[tuple]:
        """Keys of the sets in one split, sorted."""
        return sorted(k for k, s in self.assignment.items() if s == name)

    def runs(self, table: RunTable, name: str, *, measured_only: bool) -> np.ndarray:
        """Indices of the table's runs in one split (interpolated runs dropped when ``measured_only``)."""
        keys = [tuple(k) for k in table.runs["set_key"].to_list()]
        interp = table.runs["interpolated"].to_numpy()
        out = [r for r, k in enumerate(keys) if self.assignment.get(k) == name and not (measured_only and interp[r])]
        return np.asarray(out, dtype=np.int64)

    def counts(self) -> dict[str, int]:
        """Parameter sets per split."""
        return {s: sum(1 for v in self.assignment.values() if v == s) for s in SPLITS}

    def to_dict(self, table: RunTable | None = None) -> dict:
        """JSON record (with each set's runs when a table is given)."""
        runs_of: dict[tuple, list[str]] = {}
        if table is not None:
            for row in table.runs.iter_rows(named=True):
                tag = f"{row['campaign_id']}/{row['run_id']}@{row['flow_speed_mps']:.3g}"
                if row["interpolated"]:
                    tag += " (interpolated)"
                runs_of.setdefault(tuple(row["set_key"]), []).append(tag)
        sets = [{"label": set_label(self.params[k]), "split": self.assignment[k],
                 "params": dict(self.params[k]), **({"runs": runs_of.get(k, [])} if table is not None else {})}
                for k in sorted(self.assignment)]
        return {"schema": SCHEMA, "unit": "motion-parameter set", "seed": self.seed,
                "fractions": list(self.fractions), "param_columns": list(self.param_columns),
                "pin_test": [dict(p) for p in self.pin_test], "stratify": list(self.stratify),
                "counts": self.counts(), "sets": sets}

    @classmethod
    def from_dict(cls, d: Mapping, path: str | None = None) -> "ParameterSplit":
        """Read a record written by :meth:`to_dict`."""
        if d.get("schema") != SCHEMA:
            raise ContractError(f"not a split record (schema {d.get('schema')!r}, expected {SCHEMA!r})", path=path)
        cols = tuple(d["param_columns"])
        assignment, params = {}, {}
        for s in d["sets"]:
            if s["split"] not in SPLITS:
                raise ContractError(f"unknown split {s['split']!r}", path=path)
            k = set_key(s["params"], cols)
            assignment[k] = s["split"]
            params[k] = {c: float(s["params"][c]) for c in cols}
        return cls(int(d["seed"]), tuple(d["fractions"]), cols, assignment, params,
                   tuple(d.get("pin_test", ())), tuple(d.get("stratify", ())))


def _matches(params: Mapping[str, float], spec: Mapping[str, float]) -> bool:
    return all(abs(float(params[k]) - float(v)) < 10 ** -PARAM_DECIMALS * 10 for k, v in spec.items())


def _stratified_order(keys: list[tuple], params: Mapping[tuple, Mapping[str, float]],
                      stratify: Sequence[str], rng: np.random.Generator) -> list[tuple]:
    """The sets in an order whose every prefix holds each stratum in proportion to its size.

    Each stratum (one combination of the ``stratify`` parameters' values) is shuffled; its i-th set
    of m gets the position (i + u) / m with one random offset u per stratum (systematic sampling), and
    the sets are sorted by position. The test sets (the order's head) and the validation sets (next)
    thus take every stratum's share: a validation split without, say, the highest frequency would
    calibrate intervals on data unlike part of the test split.
    """
    strata: dict[tuple, list[tuple]] = {}
    for k in keys:
        strata.setdefault(tuple(round(float(params[k][c]), PARAM_DECIMALS) for c in stratify), []).append(k)
    placed = []
    for label in sorted(strata):
        members = strata[label]
        members = [members[i] for i in rng.permutation(len(members))]
        u = float(rng.random())
        placed += [((i + u) / len(members), float(rng.random()), k) for i, k in enumerate(members)]
    placed.sort(key=lambda t: (t[0], t[1]))
    return [k for _, _, k in placed]


def split_parameter_sets(table: RunTable, fractions: Sequence[float] = (0.7, 0.1, 0.2), seed: int = 0,
                         pin_test: Sequence[Mapping[str, float]] = (),
                         stratify: Sequence[str] = ()) -> ParameterSplit:
    """Assign every parameter set of the table to train, val or test (seeded, reproducible).

    Each spec in ``pin_test`` (e.g. ``{"theta_h_min_deg": 10, "theta_k_max_deg": -20}``, the
    paper's figure sets) sends one matching set (the seed picks which) to test, so the figures
    can show held-out sets; the pinned sets count towards the test share. ``stratify`` (e.g.
    ``["frequency_hz"]``) draws val and test in proportion from every value of those parameters.
    """
    cols = table.param_columns
    params = _parameter_sets(table)
    keys = sorted(params)
    n = len(keys)
    if n < 3:
        raise DataError(f"only {n} parameter set(s); a 7:1:2 split by parameter set needs at least 3",
                        hint="add runs with other motion parameters")
    for spec in pin_test:
        unknown = [k for k in spec if k not in cols]
        if unknown:
            raise ContractError(f"data.split.pin_test names unknown parameters {unknown}")
    rng = np.random.default_rng(seed)
    pinned = _pinned_sets(keys, params, pin_test, rng)
    unknown = [c for c in stratify if c not in cols]
    if unknown:
        raise ContractError(f"data.split.stratify names unknown parameters {unknown} (parameters: {list(cols)})")
    n_test, n_val, n_train = _split_sizes(n, fractions, len(pinned))
    assignment = {k: "test" for k in pinned}
    if stratify:
        assignment.update(_stratified_assignment(keys, params, stratify, rng, pinned, n_test, n_val))
    else:
        assignment.update(_plain_assignment(keys, rng, pinned, n_train, n_val))
    return ParameterSplit(seed, tuple(float(f) for f in fractions), cols, assignment, params,
                          tuple(dict(p) for p in pin_test), tuple(stratify))


def _parameter_sets(table: RunTable) -> dict[tuple, dict]:
    """Set key -> the set's parameter values, for every motion-parameter set of the table."""
    cols = table.param_columns
    params: dict[tuple, dict] = {}
    for row in table.runs.select(list(cols)).iter_rows(named=True):
        params.setdefault(set_key(row, cols), {c: float(row[c]) for c in cols})
    return params


def _pinned_sets(keys: list[tuple], params: Mapping[tuple, Mapping[str, float]],
                 pin_test: Sequence[Mapping[str, float]], rng: np.random.Generator) -> list[tuple]:
    """One matching set per ``pin_test`` spec (the generator picks which; a spec matching no set left out)."""
    pinned: list[tuple] = []
    for spec in pin_test:
        cand = [k for k in keys if _matches(params[k], spec) and k not in pinned]
        if cand:
            pinned.append(cand[int(rng.integers(len(cand)))])
    return pinned


def _split_sizes(n: int, fractions: Sequence[float], n_pinned: int) -> tuple[int, int, int]:
    """Sets in (test, val, train): the fractions' shares, at least one where the fraction is positive."""
    n_test = max(int(round(fractions[2] * n)), n_pinned, 1 if fractions[2] > 0 else 0)
    n_val = max(int(round(fractions[1] * n)), 1 if fractions[1] > 0 else 0)
    n_train = n - n_test - n_val
    if n_train < 1:
        raise DataError(f"{n} parameter sets are too few for fractions {list(fractions)}")
    return n_test, n_val, n_train


def _stratified_assignment(keys: list[tuple], params: Mapping[tuple, Mapping[str, float]], stratify: Sequence[str],
                           rng: np.random.Generator, pinned: list[tuple], n_test: int, n_val: int) -> dict[tuple, str]:
    """The unpinned sets in stratified order: test first (the pinned sets already hold part of it), then val, train."""
    order = [k for k in _stratified_order(keys, params, stratify, rng) if k not in pinned]
    n_free_test = n_test - len(pinned)
    return {k: "test" if i < n_free_test else ("val" if i < n_free_test + n_val else "train")
            for i, k in enumerate(order)}


def _plain_assignment(keys: list[tuple], rng: np.random.Generator, pinned: list[tuple], n_train: int,
                      n_val: int) -> dict[tuple, str]:
    """The unpinned sets in a seeded random order: train first, then val, then test."""
    rest = [keys[i] for i in rng.permutation(len(keys)) if keys[i] not in pinned]
    return {k: "train" if i < n_train else ("val" if i < n_train + n_val else "test") for i, k in enumerate(rest)}
