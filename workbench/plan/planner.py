"""``workbench plan-campaign``: propose the next tunnel campaign and write it as a manifest with no files yet.

Pieces: the FED-LSTM ensemble (:mod:`workbench.learn.ensemble`), the operating region of the
retained gaits (:mod:`workbench.plan.region`), candidate runs within the rig's ranges, the runs a
diagnosis asks for (:mod:`workbench.plan.diagnosis_runs`) and the integrated-variance greedy
batch (:mod:`workbench.plan.acquisition`). Output: ``PLAN.toml`` (contract v1 campaign manifest,
runs with motion parameters, flow speed and cycles, no file entries) and ``plan.md`` beside it,
returned as texts (:func:`plan_texts`); ``workbench.commands.plan_campaign`` reads the inputs and
writes the two files as one set.
"""

from __future__ import annotations

import datetime as _dt
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.errors import ContractError
from workbench.plan.acquisition import Candidate, RigRanges

PLAN_NOTE = "planned by workbench plan-campaign: runs to measure, files pending"


@dataclass(frozen=True)
class PlanSettings:
    """The knobs of pipelines/plan.yaml's ``plan`` section."""

    n_candidates: int = 160
    seed: int = 0
    lengthscale: float = 0.5
    points_per_run: int = 6
    region_points_per_cycle: int = 8
    region_cycles: float = 1.0
    swim_s: float = 12.0
    max_rank: int | None = None
    ranges: RigRanges = field(default_factory=RigRanges)
    loadcell: Mapping[str, Any] = field(default_factory=lambda: {"model": "DMI D6095XA", "rate_hz": 500.0,
                                                                 "full_scale": [50.0, 50.0, 50.0, 2.0, 2.0, 2.0]})
    motion: Mapping[str, Any] = field(default_factory=lambda: {"rate_hz": 65.0, "feedback": False})

    @classmethod
    def from_dict(cls, doc: Mapping | None, path: str | Path | None = None) -> "PlanSettings":
        """From the ``plan`` section, through :func:`workbench.params.build`.

        Unknown keys, wrong types and bad ranges are a :class:`~workbench.errors.ParamsError` naming
        ``path``, the key path and the allowed keys.
        """
        from workbench.params import build

        return build(cls, doc, key="plan", path=path)


def _plan_id(out: Path, given: str | None) -> str:
    from workbench.contract.columns import CAMPAIGN_ID_PATTERN

    cid = given or re.sub(r"[^a-z0-9_-]", "-", out.stem.lower()).strip("-") or "next-campaign"
    if not re.match(CAMPAIGN_ID_PATTERN, cid):
        raise ContractError(f"campaign id {cid!r} is not valid {CAMPAIGN_ID_PATTERN}", hint="pass --id")
    return cid


def plan_campaign(ensemble, gait_files: Sequence, n_runs: int, out: str | Path, *, diagnosis: dict | None = None,
                  settings: PlanSettings | None = None, campaign_id: str | None = None, robot=None,
                  ensemble_dir: str | Path | None = None, region=None, legs=None) -> dict:
    """Propose ``n_runs`` runs (plus the diagnosis's); returns the plan record.

    Takes data; the command reads and writes (``workbench.commands.plan_campaign.plan_from_files``).
    ``ensemble``: the FED-LSTM ensemble (:func:`workbench.learn.ensemble.load_ensemble`),
    ``ensemble_dir`` its folder (named in the record); ``gait_files``: the retained gaits
    (:func:`workbench.plan.region.gait_files_from_docs`); ``out``: the manifest's path (its name
    gives the default campaign id; nothing is written here); ``diagnosis``: a diagnosis.json
    document (:func:`workbench.plan.diagnosis_runs.check_diagnosis`); ``robot``: the robot's
    constants for the swims (default: the built-in ones). ``region``: an operating region already
    computed from ``gait_files`` (:func:`~workbench.plan.region.operating_region`), to skip the
    swims; ``legs``: which legs swim each gait file's gaits (see there; default EF).

    The record holds the runs with their reasons and gains, region variance before/after, tunnel
    time and costs; :func:`plan_texts` makes the manifest and plan.md of it.
    """
    from workbench.plan.acquisition import IntegratedVariance, greedy_select, random_candidates
    from workbench.plan.region import operating_region, retained_params

    if n_runs < 0:
        raise ContractError(f"--n-runs must be >= 0, got {n_runs}")
    s = settings or PlanSettings()
    out = Path(out)
    cid = _plan_id(out, campaign_id)
    t0 = time.perf_counter()
    if region is None:
        if robot is None:
            from workbench.hydro.robot import RobotSettings

            robot = RobotSettings()
        region = operating_region(gait_files, robot, duration_s=s.swim_s, cycles=s.region_cycles,
                                  points_per_cycle=s.region_points_per_cycle, legs=legs)
    t_region = time.perf_counter()
    cands = random_candidates(s.ranges, s.n_candidates, s.seed)
    forced: list[int] = []
    pairs: list = []
    if diagnosis is not None:
        from workbench.plan.diagnosis_runs import ambiguous_pairs, diagnosis_runs, region_stroke

        pairs = ambiguous_pairs(diagnosis)
        extra = diagnosis_runs(diagnosis, s.ranges, region_stroke(retained_params(gait_files), s.ranges))
        forced = list(range(len(cands), len(cands) + len(extra)))
        cands = cands + extra
    iv = IntegratedVariance(ensemble, region, cands, lengthscale=s.lengthscale, points_per_run=s.points_per_run)
    sel = greedy_select(iv, n_runs + len(forced), s.ranges, forced)
    t_sel = time.perf_counter()
    runs = _ordered_runs(cands, sel, s.ranges)
    record = {
        "campaign_id": cid, "runs": runs, "n_runs": len(runs), "n_diagnosis_runs": len(forced),
        "ambiguous_pairs": [list(p) for p in pairs],
        "tunnel_s": sum(r["tunnel_s"] for r in runs),
        "region": region.summary(), "region_var_before": sel.region_var_before,
        "region_var_after": sel.region_var_after, "total_before": sel.total_before, "total_after": sel.total_after,
        "ensemble": {"dir": None if ensemble_dir is None else str(ensemble_dir), "members": len(ensemble.members),
                     "coverage_test_after": ensemble.record.get("calibration", {}).get("coverage_test_after")},
        "settings": {"n_candidates": s.n_candidates, "lengthscale": s.lengthscale, "points_per_run": s.points_per_run,
                     "setup_s": s.ranges.setup_s, "cycles": s.ranges.cycles, "seed": s.seed},
        "cost_s": {"region": t_region - t0, "select": t_sel - t_region, "total": t_sel - t0},
    }
    return record


def _ordered_runs(cands: Sequence[Candidate], sel, ranges: RigRanges) -> list[dict]:
    """Chosen runs with reasons, ordered by flow speed (one flow change per speed), ids p001, p002, ..."""
    total = max(sel.total_before, 1e-30)
    picked = []
    for rank, (j, g, sec) in enumerate(zip(sel.chosen, sel.gains, sel.seconds, strict=True)):
        c = cands[j]
        why = c.notes[0] if c.notes else "largest drop of the region-weighted model variance per tunnel second"
        picked.append({"pick": rank + 1, "flow_speed_mps": c.flow_speed_mps, "params": dict(c.params),
                       "cycles": c.cycles, "tunnel_s": sec, "gain": g, "gain_share": g / total, "why": why,
                       "kind": c.reason})
    picked.sort(key=lambda r: (r["flow_speed_mps"], r["pick"]))
    for i, r in enumerate(picked):
        r["id"] = f"p{i + 1:03d}"
    return picked


def manifest_text(record: dict, s: PlanSettings, date: str | None) -> str:
    """The contract-v1 campaign.toml of the plan: runs with parameters, flow speed and cycles, no files.

    Written by the contract's campaign.toml writer (:func:`workbench.contract.toml_text.campaign_toml`),
    the one the virtual lab's campaigns are written with.
    """
    from workbench.contract.toml_text import campaign_toml

    day = date or _dt.date.today().isoformat()
    head = {"schema": "workbench/campaign@1", "id": record["campaign_id"], "facility": "water_tunnel", "date": day,
            "description": f"{PLAN_NOTE} ({record['n_runs']} runs, {record['tunnel_s'] / 60:.1f} tunnel minutes); "
                           "see plan.md"}
    tables = {"loadcell": dict(s.loadcell), "motion": dict(s.motion)}
    runs = [{"id": r["id"], "flow_speed_mps": float(r["flow_speed_mps"]), **{k: float(v) for k, v in r["params"].items()},
             "cycles": int(r["cycles"])} for r in record["runs"]]
    lines = ["# A PLAN: no run has been measured yet, so no run names its files (loadcell/motion or mcap).",
             "# Measure each run as given (the rig's controller, or `workbench virtual-lab tunnel DIR --plan THIS`),",
             "# then add the file entries per run and `workbench campaign add DIR`. Why each run: plan.md.", ""]
    return "\n".join(lines) + campaign_toml(head, tables, runs)


def plan_markdown(record: dict, out_name: str) -> str:
    """plan.md: why each run, its expected gain, the tunnel time."""
    rs = record["runs"]
    lines = [f"# Plan {record['campaign_id']}: {len(rs)} runs, {record['tunnel_s'] / 60:.1f} tunnel minutes", "",
             f"Manifest: `{out_name}` (contract v1, files pending). Measure the runs in this order (one flow change "
             "per speed).", "",
             "Method: the FED-LSTM ensemble's variance at the states the retained gaits put the legs in (the "
             "operating region), reduced run by run (greedy integrated posterior variance over the ensemble, "
             "localised in state space); each pick maximises the variance it removes per second of tunnel time.", "",
             f"Region: {record['region']['legs']} legs of the retained gaits ({', '.join(record['region']['gait_files'])}), "
             f"{record['region']['points']} points; leg flow {record['region']['flow_speed_mps'][0]:.3f} to "
             f"{record['region']['flow_speed_mps'][1]:.3f} m/s; swum with "
             f"{'; '.join(record['region'].get('leg_models') or ['EF legs'])}.", "",
             f"Region-weighted model variance (noise units, all channels): {record['total_before']:.3g} now, "
             f"{record['total_after']:.3g} expected after this campaign "
             f"({100 * (1 - record['total_after'] / max(record['total_before'], 1e-30)):.0f} % less).", "",
             "| id | flow m/s | theta_h_min | theta_k_max | f Hz | phi rad | cycles | tunnel s | expected gain | why |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rs:
        p = r["params"]
        lines.append(f"| {r['id']} | {r['flow_speed_mps']:.2f} | {p['theta_h_min_deg']:g} | {p['theta_k_max_deg']:g} | "
                     f"{p['frequency_hz']:g} | {p['phi_rad']:.3g} | {r['cycles']} | {r['tunnel_s']:.0f} | "
                     f"{100 * r['gain_share']:.1f} % (pick {r['pick']}) | {r['why']} |")
    lines += ["", "Expected gain: share of today's region-weighted variance the run removes given the runs picked "
              "before it. Tunnel time per run: cycles / frequency plus "
              f"{record['settings']['setup_s']:g} s setup.", "", "Region variance per channel (calibrated members' "
              "variance, physical units): before -> after", ""]
    for c in WRENCH_CHANNELS:
        lines.append(f"- {c}: {record['region_var_before'][c]:.3g} -> {record['region_var_after'][c]:.3g}")
    if record["ambiguous_pairs"]:
        lines += ["", "Diagnosis: ambiguous pairs " + "; ".join(" vs ".join(p) for p in record["ambiguous_pairs"])
                  + f" -> {record['n_diagnosis_runs']} run(s) picked first."]
    cov = record["ensemble"].get("coverage_test_after")
    if cov:
        lines += ["", "Ensemble 90 % interval coverage on held-out test readings: "
                  + ", ".join(f"{c} {100 * v:.0f} %" for c, v in cov.items())]
    return "\n".join(lines) + "\n"


def plan_texts(out: str | Path, record: dict, s: PlanSettings, date: str | None) -> dict[str, str]:
    """``{file name: text}``: the manifest (named as ``out``) and plan.md beside it, written by the command as one set."""
    out = Path(out)
    report = out.with_name("plan.md") if out.name != "plan.md" else out.with_suffix(".report.md")
    return {out.name: manifest_text(record, s, date), report.name: plan_markdown(record, out.name)}
