"""Column names, channel names and manifest keys fixed by data contract v1."""

from __future__ import annotations

CAMPAIGN_SCHEMA = "workbench/campaign@1"
TRIALS_SCHEMA = "workbench/trials@1"

FACILITIES = ("water_tunnel", "towing_tank")
HEADINGS = ("forward", "lateral")

#: The six load-cell channels, in contract order (forces in N, torques in N m).
WRENCH_CHANNELS = ("fx_n", "fy_n", "fz_n", "tx_nm", "ty_nm", "tz_nm")

LOADCELL_COLUMNS = ("time_s", *WRENCH_CHANNELS, "sync")
MOTION_COLUMNS = ("time_s", "hfe_cmd_deg", "kfe_cmd_deg", "sync")
MOTION_FEEDBACK_COLUMNS = ("hfe_meas_deg", "kfe_meas_deg")
CARRIAGE_COLUMNS = ("time_s", "position_m", "sync")

#: Prescribed-motion parameters of a water-tunnel run (paper equation 3), manifest names.
TUNNEL_MOTION_PARAMS = (
    "theta_h_min_deg",
    "theta_h_max_deg",
    "theta_k_min_deg",
    "theta_k_max_deg",
    "frequency_hz",
    "phi_rad",
    "alpha_rad",
)
#: Optional run keys with defaults when absent.
TUNNEL_OPTIONAL_DEFAULTS = {"alpha_rad": 0.0}

#: Processed-dataset columns (contract section 3).
PROCESSED_TUNNEL_COLUMNS = (
    "campaign_id",
    "run_id",
    "time_s",
    "flow_speed_mps",
    "theta_h_deg",
    "theta_k_deg",
    "omega_h_dps",
    "omega_k_dps",
    *WRENCH_CHANNELS,
    "interpolated",
)
PROCESSED_TOWING_COLUMNS = (
    "campaign_id",
    "run_id",
    "time_s",
    "flow_speed_mps",
    "position_m",
    "speed_mps",
    *WRENCH_CHANNELS,
    "interpolated",
)

#: MCAP topics and schema names (contract section 1).
MCAP_WRENCH_TOPIC = "/loadcell/wrench"
MCAP_WRENCH_SCHEMA = "workbench.Wrench"
MCAP_JOINT_TOPIC = "/leg/joint_command"
MCAP_JOINT_SCHEMA = "workbench.JointCommand"
MCAP_CARRIAGE_TOPIC = "/carriage/position"
MCAP_CARRIAGE_SCHEMA = "workbench.CarriagePosition"

#: Trigger-line timing on the controller clock (contract: pulse every 1.000 s, high for 0.1 s).
TRIGGER_PERIOD_S = 1.0
TRIGGER_HIGH_S = 0.1

CAMPAIGN_ID_PATTERN = r"^[a-z0-9][a-z0-9_-]{0,63}$"
