"""Manifest plausibility limits, part by part: the rig's tables and each run (values planted here)."""

from pathlib import Path
from types import MappingProxyType

from workbench.contract.campaign import Campaign, LoadCellSpec, MotionSpec, RunSpec
from workbench.contract.limits import Limits, _rig_faults, _run_faults, manifest_faults

LIMITS = Limits(flow_speed_mps_max=2.0, frequency_hz_max=5.0, angle_deg_max=360.0, phase_rad_max=6.5,
                cycles_max=10_000, run_duration_s_max=3600.0, rate_hz_max=1e5, force_abs_max_n=2000.0,
                torque_abs_max_nm=200.0)


def collect():
    seen = []

    def add(fault, key, *, run=None, where=None):
        seen.append((fault.split(" =")[0], key, run, where))
    return seen, add


def run(rid="r1", speed=0.5, cycles=None, **params):
    return RunSpec(id=rid, flow_speed_mps=speed, params=MappingProxyType(params), cycles=cycles)


def test_run_within_limits_has_no_fault():
    seen, add = collect()
    _run_faults(run(speed=2.0, cycles=100, frequency_hz=5.0, theta_h_min_deg=-360.0, phi_rad=6.5), LIMITS, add)
    assert seen == []


def test_each_run_field_beyond_its_limit_is_named():
    seen, add = collect()
    _run_faults(run(speed=2.5, frequency_hz=6.0, theta_k_max_deg=-400.0, alpha_rad=7.0), LIMITS, add)
    assert seen == [("flow_speed_mps", "flow_speed_mps_max", "r1", "field flow_speed_mps"),
                    ("theta_k_max_deg", "angle_deg_max", "r1", "field theta_k_max_deg"),
                    ("alpha_rad", "phase_rad_max", "r1", "field alpha_rad"),
                    ("frequency_hz", "frequency_hz_max", "r1", "field frequency_hz")]


def test_cycles_too_many_or_a_run_too_long():
    seen, add = collect()
    _run_faults(run(cycles=20_000, frequency_hz=1.0), LIMITS, add)
    _run_faults(run(rid="r2", cycles=5000, frequency_hz=1.0), LIMITS, add)     # 5000 s > 3600 s
    _run_faults(run(rid="r3", cycles=5000, frequency_hz=2.0), LIMITS, add)     # 2500 s: fine
    assert seen == [("cycles", "cycles_max", "r1", "field cycles"),
                    ("cycles / frequency_hz", "run_duration_s_max", "r2", "field cycles")]


def test_rig_tables_rates_and_full_scale():
    seen, add = collect()
    lc = LoadCellSpec(model="m", rate_hz=2e5, full_scale=(100.0, 3000.0, 100.0, 10.0, 10.0, 250.0))
    camp = Campaign(root=Path("c"), id="c", facility="water_tunnel", date=None, description="", loadcell=lc,
                    motion=MotionSpec(rate_hz=float("nan")), runs=())
    _rig_faults(camp, LIMITS, add)
    assert seen == [("rate_hz", "rate_hz_max", None, "[loadcell] rate_hz"),
                    ("full_scale fy", "force_abs_max_n", None, "[loadcell] full_scale"),
                    ("full_scale tz", "torque_abs_max_nm", None, "[loadcell] full_scale")]


def test_manifest_faults_gathers_rig_then_runs_with_hints():
    lc = LoadCellSpec(model="m", rate_hz=500.0)
    camp = Campaign(root=Path("c"), id="c", facility="water_tunnel", date=None, description="", loadcell=lc,
                    motion=MotionSpec(rate_hz=2e5), runs=(run(speed=9.0), run(rid="r2", frequency_hz=9.0)))
    errors = manifest_faults(camp, LIMITS)
    assert [(e.run, e.where) for e in errors] == [(None, "[motion] rate_hz"), ("r1", "field flow_speed_mps"),
                                                  ("r2", "field frequency_hz")]
    assert all(Path(e.path) == Path("c/campaign.toml") for e in errors)
    assert "ingest.limits.flow_speed_mps_max" in errors[1].hint
