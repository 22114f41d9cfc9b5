"""``workbench interpolate IN --out OUT``: add flow-speed-interpolated runs to a processed tunnel file."""

from __future__ import annotations

from pathlib import Path

from workbench.commands._help import add_verb
from workbench.commands.ingest import PARAMS_FILE


def register(sub) -> None:
    """Add the ``interpolate`` verb."""
    p = add_verb(
        sub, "interpolate", help="add runs at intermediate flow speeds (paper III-B-2) to a processed file",
        description="For each motion parameter set measured at three or more flow speeds, make runs at the "
        "intermediate speeds (0.05, 0.15, 0.25 m/s by default) by a quadratic fit across the measured speeds at "
        "every phase point, low-pass them, and write measured + interpolated rows (interpolated = true, run id "
        "'<run>@v<speed>'). Parameters: the 'interpolate' section of "
        f"{PARAMS_FILE}; see docs/ingest.md.",
        examples="""\
  workbench interpolate datasets/processed/demo-tunnel.parquet --out datasets/processed/interp/demo-tunnel.parquet
  workbench interpolate in.parquet --out out.parquet --speeds 0.05 0.15 0.25 0.35 --extrapolate
""")
    p.add_argument("input", type=Path, help="processed tunnel file (from workbench ingest)")
    p.add_argument("--out", type=Path, required=True, help="output file")
    p.add_argument("--speeds", type=float, nargs="+", default=None, help="flow speeds to make (m/s)")
    p.add_argument("--extrapolate", action="store_true", help="also make speeds outside the measured range")
    p.add_argument("--params", type=Path, default=None,
                   help=f"parameter file with an 'interpolate' section (default: {PARAMS_FILE} if present)")
    p.set_defaults(func=run)


def run(args) -> int:
    """Read, interpolate, write atomically with the input's provenance plus the interpolation's."""
    import time

    from workbench.console import info
    from workbench.errors import ContractError
    from workbench.ingest import read_processed, read_provenance
    from workbench.ingest.provenance import to_arrow, write_table
    from workbench.params import load_settings
    from workbench.signals.interpolation import InterpolationSettings, interpolate_with_report

    params = load_settings(InterpolationSettings, args.params, "interpolate", default=PARAMS_FILE,
                           overrides={"speeds_mps": args.speeds or None, "extrapolate": args.extrapolate or None})
    meta = read_provenance(args.input)
    if meta.get("facility") != "water_tunnel":
        raise ContractError("flow-speed interpolation applies to water-tunnel datasets", path=args.input)
    t0 = time.perf_counter()
    frame, report = interpolate_with_report(read_processed(args.input), params)
    meta = dict(meta)
    meta["interpolation"] = {"params": {**params.__dict__, "speeds_mps": list(params.speeds_mps)},
                             "input": str(args.input), **report.as_dict()}
    write_table(to_arrow(frame, "water_tunnel", meta), args.out)
    made = frame.filter(frame["interpolated"]).height
    info(f"interpolated {len(report.made)} run(s) ({made:,} rows) at {list(params.speeds_mps)} m/s from "
         f"{meta['quality']['runs_ingested']} measured run(s) in {time.perf_counter() - t0:.1f} s; "
         f"{len(report.skipped_sets)} parameter set(s) left alone; wrote {args.out}")
    return 0
