"""Maskell's prior for ``tunnel_blockage`` (issue 13, item 4): the manifest's ``[tunnel]`` table, the prior, the fit.

The blockage is planted physically: the virtual tunnel runs its water at ``U sqrt(1 + eps)``
while the manifest keeps the nominal speed ``U`` (what a lab's flow meter upstream of a blocked
test section reads). Maskell's value is computed here from the motion file with the test's own
formula for the web's frontal area.
"""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
from diag_helpers import grid

EPS_TRUE = 0.08
SPEEDS = (0.0, 0.12, 0.25)


def _tiny(root: Path, name: str, n_sets: int = 1, cycles: int = 1, speed_factor: float = 1.0) -> Path:
    """A virtual EF-truth tunnel campaign run at ``speed_factor`` times the speeds its manifest states."""
    from workbench.virtual_lab.tunnel import generate_tunnel

    out = generate_tunnel(root / name, seed=3, truth="ef", grid=grid(n_sets), cycles=cycles,
                          flow_speeds=[u * speed_factor for u in SPEEDS], campaign_id=name)
    if speed_factor != 1.0:
        man = out / "campaign.toml"
        text = man.read_text()
        for u in SPEEDS[1:]:
            text = re.sub(rf"flow_speed_mps = {re.escape(repr(u * speed_factor))}\b", f"flow_speed_mps = {u!r}", text)
        man.write_text(text)
        speeds = {float(r["flow_speed_mps"]) for r in tomllib.loads(text)["runs"]}
        assert speeds == set(SPEEDS), speeds
    (out / "truth.json").unlink(missing_ok=True)
    return out


def _add_area(folder: Path, area) -> None:
    man = folder / "campaign.toml"
    man.write_text(man.read_text() + f"\n[tunnel]\ntest_section_area_m2 = {area}\n")


def test_the_tunnel_table_is_optional_and_checked(tmp_path):
    from workbench.contract.campaign import check_manifest, load_campaign

    folder = _tiny(tmp_path, "tiny-tunnel")
    assert load_campaign(folder).test_section_area_m2 is None      # contract v1 manifests are unchanged
    _add_area(folder, 0.09)
    assert load_campaign(folder).test_section_area_m2 == pytest.approx(0.09)
    man = folder / "campaign.toml"
    man.write_text(man.read_text().replace("test_section_area_m2 = 0.09", "test_section_area_m2 = -1"))
    _, errors = check_manifest(folder)
    assert len(errors) == 1
    msg = str(errors[0])
    assert "campaign.toml" in msg and "[tunnel] test_section_area_m2" in msg and "positive" in msg


def test_the_posterior_minimises_data_misfit_plus_prior_penalty():
    """A Gaussian prior on one of two correlated coefficients: the posterior mean is the penalised optimum."""
    from scipy import optimize

    from workbench.diagnose.lsq import _posterior

    theta = np.array([0.3, -1.2, 5.0])          # the third is fixed (not free)
    fi = np.array([0, 1])
    cov = np.array([[0.04, 0.015], [0.015, 0.02]])
    prior = {"a": (0.1, 0.15)}
    post, post_cov = _posterior(theta, fi, cov, prior, ["a", "b", "c"])

    ci = np.linalg.inv(cov)

    def objective(x):
        d = x - theta[:2]
        return d @ ci @ d + (x[0] - 0.1) ** 2 / 0.15 ** 2

    best = optimize.minimize(objective, theta[:2], method="BFGS", options={"gtol": 1e-12}).x
    assert post[:2] == pytest.approx(best, abs=1e-6)
    assert post[2] == theta[2]
    # the posterior variance of the first is below both the data's and the prior's
    assert post_cov[0, 0] < min(cov[0, 0], 0.15 ** 2)
    # the correlated coefficient moved with it (blockage against a drag coefficient)
    assert abs(post[1] - theta[1]) > 1e-3


def _maskell_here(folder: Path, area: float, theta: float = 2.5, c_d: float = 1.17) -> float:
    """Maskell's epsilon from the motion files: theta C_D S_web mean|cos(theta_h + theta_k)| / C over flowing runs.

    The web's normal in the leg plane makes the angle theta_h + theta_k with the stream (the web
    lies along the calf), so its frontal area is S_web |cos(theta_h + theta_k)|; averaged over
    the moving part of each run (after the first trigger edge).
    """
    doc = tomllib.loads((folder / "campaign.toml").read_text())
    vals = []
    for run in doc["runs"]:
        if float(run["flow_speed_mps"]) <= 0:
            continue
        data = np.loadtxt(folder / run["motion"], delimiter=",", skiprows=1)
        t, th, tk, sync = data[:, 0], data[:, 1], data[:, 2], data[:, 3]
        start = t[np.flatnonzero(sync > 0.5)[0]]
        moving = (t >= start + 0.5) & (t <= t[-1] - 0.5)
        vals.append(np.mean(np.abs(np.cos(np.radians(th[moving] + tk[moving])))))
    return theta * c_d * 0.06 ** 2 * float(np.mean(vals)) / area


def _diagnose(folder: Path, out: Path, *extra: str) -> dict:
    cmd = [sys.executable, "-m", "workbench", "diagnose", "--campaign", str(folder), "--model", "ef",
           "--effects", "tunnel_blockage", "--out", str(out), "--no-mlflow", "--no-figures", *extra]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-2000:]
    return json.loads((out / "diagnosis.json").read_text())


@pytest.mark.slow
def test_maskell_prior_from_the_manifest_on_a_planted_blockage(tmp_path):
    folder = _tiny(tmp_path, "blocked", n_sets=12, cycles=4, speed_factor=math.sqrt(1 + EPS_TRUE))
    area = 0.09                                    # a 0.3 m x 0.3 m test section
    _add_area(folder, area)
    expected_prior = _maskell_here(folder, area)
    assert 0.02 < expected_prior < 0.3             # a plausible blockage for this cross-section

    doc = _diagnose(folder, tmp_path / "with-prior")
    eff = {e["name"]: e for e in doc["effects"]}["tunnel_blockage"]
    p = eff["params"]
    assert p["epsilon_prior"] == pytest.approx(expected_prior, rel=0.05)
    assert p["epsilon_prior_sd"] == pytest.approx(0.5 * expected_prior, rel=0.05)
    # an EF-truth campaign determines the blockage well: the data win over the prior
    assert p["epsilon"] == pytest.approx(EPS_TRUE, rel=0.2)
    assert p["epsilon_data"] == pytest.approx(EPS_TRUE, rel=0.2)
    # ... and the posterior lies between the data and the prior
    lo, hi = sorted((p["epsilon_data"], p["epsilon_prior"]))
    assert lo - 1e-9 <= p["epsilon"] <= hi + 1e-9
    report = (tmp_path / "with-prior" / "report.md").read_text()
    assert "epsilon_prior" in report
    # the saved augmented model rebuilds the prior's effect and predicts on a motion of its own
    from workbench.diagnose.augmented import load_augmented
    from workbench.hydro.motion import LegMotion

    aug = load_augmented(tmp_path / "with-prior")
    z = np.zeros((2, 200))
    tt = np.arange(200) / 65
    th, tk = -45 + 30 * np.sin(2 * np.pi * 0.5 * tt), 40 + 20 * np.cos(2 * np.pi * 0.5 * tt)
    motion = LegMotion(1 / 65, z + th, z + tk, z + 30 * 2 * np.pi * 0.5 * np.cos(2 * np.pi * 0.5 * tt),
                       z - 20 * 2 * np.pi * 0.5 * np.sin(2 * np.pi * 0.5 * tt), z + np.array([[0.0], [0.2]]))
    w, w0 = aug.wrench(motion), aug.base.wrench(motion)
    assert np.all(np.isfinite(w))
    assert np.allclose(w[0], aug.lowpass(w0, 1 / 65, axis=-2)[0], atol=1e-9)     # no flow: no blockage
    assert not np.allclose(w[1], aug.lowpass(w0, 1 / 65, axis=-2)[1], atol=1e-6)

    # the same campaign without the table: the searched epsilon, as before; with --tunnel-area: the prior again
    man = folder / "campaign.toml"
    man.write_text(man.read_text().split("\n[tunnel]")[0] + "\n")
    plain = {e["name"]: e for e in _diagnose(folder, tmp_path / "plain")["effects"]}["tunnel_blockage"]["params"]
    assert "epsilon_prior" not in plain
    assert plain["epsilon"] == pytest.approx(EPS_TRUE, rel=0.2)
    opt = {e["name"]: e for e in _diagnose(folder, tmp_path / "option", "--tunnel-area", str(area))["effects"]}
    assert opt["tunnel_blockage"]["params"]["epsilon_prior"] == pytest.approx(p["epsilon_prior"], rel=1e-6)
