"""Raw files exactly per data contract v1: CSV pairs, ``.bin`` serial captures, MCAP, campaign.toml.

Writers take arrays and a target path inside the (temporary) campaign folder the generator is
building; the generator swaps the whole folder in atomically. Output is byte-for-byte
deterministic: fixed float formatting, no wall-clock time anywhere.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import polars as pl

from workbench.contract.columns import (
    CARRIAGE_COLUMNS,
    LOADCELL_COLUMNS,
    MCAP_CARRIAGE_SCHEMA,
    MCAP_CARRIAGE_TOPIC,
    MCAP_JOINT_SCHEMA,
    MCAP_JOINT_TOPIC,
    MCAP_WRENCH_SCHEMA,
    MCAP_WRENCH_TOPIC,
    MOTION_COLUMNS,
    MOTION_FEEDBACK_COLUMNS,
    WRENCH_CHANNELS,
)
from workbench.contract.serial import FRAME_SIZE, counts_from_si, encode_frames
from workbench.contract.toml_text import campaign_toml

#: decimals written for every float column (1 us, 1 uN, 1 uN m, 1e-6 deg, 1 um)
DECIMALS = 6


def loadcell_columns(t_daq: np.ndarray, wrench: np.ndarray, sync: np.ndarray) -> dict[str, np.ndarray]:
    """Load-cell columns in contract order."""
    cols = {"time_s": t_daq}
    cols.update({c: wrench[:, i] for i, c in enumerate(WRENCH_CHANNELS)})
    cols["sync"] = sync
    assert tuple(cols) == LOADCELL_COLUMNS
    return cols


def motion_columns(t_ctrl: np.ndarray, hfe_cmd: np.ndarray, kfe_cmd: np.ndarray, sync: np.ndarray,
                   measured: tuple[np.ndarray, np.ndarray] | None = None) -> dict[str, np.ndarray]:
    """Motion-log columns in contract order (measured angles last, when fed back)."""
    cols = dict(zip(MOTION_COLUMNS, (t_ctrl, hfe_cmd, kfe_cmd, sync), strict=True))
    if measured is not None:
        cols.update(dict(zip(MOTION_FEEDBACK_COLUMNS, measured, strict=True)))
    return cols


def carriage_columns(t_ctrl: np.ndarray, position_m: np.ndarray, sync: np.ndarray) -> dict[str, np.ndarray]:
    """Carriage-log columns in contract order."""
    return dict(zip(CARRIAGE_COLUMNS, (t_ctrl, position_m, sync), strict=True))


def _frame(cols: Mapping[str, np.ndarray]) -> pl.DataFrame:
    data = {}
    for name, v in cols.items():
        v = np.asarray(v)
        data[name] = pl.Series(name, v.astype(np.int64) if name == "sync" else v.astype(np.float64))
    return pl.DataFrame(data)


def write_csv(path: Path, cols: Mapping[str, np.ndarray]) -> None:
    """A CSV with the columns' names as header, floats with fixed decimals, ``sync`` as 0/1."""
    path.parent.mkdir(parents=True, exist_ok=True)
    _frame(cols).write_csv(path, float_precision=DECIMALS, line_terminator="\n")


def write_bin(path: Path, t_daq: np.ndarray, wrench: np.ndarray, sync: np.ndarray, calibration: np.ndarray,
              faults: Mapping[str, Any] | None = None, rng: np.random.Generator | None = None) -> dict:
    """A serial capture of 32-byte frames; optionally with the faults a real logger meets.

    ``faults`` may ask for ``mid_frame`` (the capture starts inside a frame: the tail of one
    more frame first), ``corrupt`` (that many frames get one byte changed: bad checksum) and
    ``drop`` (that many frames lose a few bytes). Returns what was done, for truth.json.
    """
    time_us = np.round(np.asarray(t_daq) * 1e6).astype(np.int64)
    counts = counts_from_si(wrench, calibration)
    raw = bytearray(encode_frames(time_us, counts, sync))
    report: dict[str, Any] = {"frames": int(len(time_us)), "corrupted_frames": [], "dropped": []}
    faults = dict(faults or {})
    n = len(time_us)
    if faults and rng is not None and n > 20:
        picks = rng.choice(np.arange(5, n - 5), size=int(faults.get("corrupt", 0)) + int(faults.get("drop", 0)),
                           replace=False)
        corrupt = sorted(int(i) for i in picks[: int(faults.get("corrupt", 0))])
        drop = sorted((int(i) for i in picks[int(faults.get("corrupt", 0)):]), reverse=True)
        for i in corrupt:
            pos = i * FRAME_SIZE + 6 + int(rng.integers(0, 24))  # a count byte: checksum no longer matches
            raw[pos] = (raw[pos] + 1 + int(rng.integers(0, 254))) % 256
        for i in drop:
            k = int(rng.integers(1, 6))
            pos = i * FRAME_SIZE + int(rng.integers(2, FRAME_SIZE - k))
            del raw[pos:pos + k]
            report["dropped"].append({"frame": i, "bytes": k})
        report["corrupted_frames"] = corrupt
        report["dropped"].sort(key=lambda d: d["frame"])
    if faults.get("mid_frame"):
        k = int(faults.get("mid_frame_bytes", 13))
        period = int(time_us[1] - time_us[0]) if n > 1 else 1000
        prefix = encode_frames(time_us[:1] - period, counts[:1], sync[:1])[-k:]  # the tail of the frame before
        raw[:0] = prefix
        report["mid_frame_prefix_bytes"] = k
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(bytes(raw))
    return report


# ------------------------------------------------------------------------------ MCAP
def _schema(columns: Sequence[str]) -> bytes:
    props = {c: ({"type": "integer"} if c == "sync" else {"type": "number"}) for c in columns}
    return json.dumps({"type": "object", "properties": props, "required": list(columns)},
                      separators=(",", ":")).encode()


def _messages(cols: Mapping[str, np.ndarray]) -> list[bytes]:
    names = list(cols)
    fmt = "{" + ",".join(f'"{c}":%d' if c == "sync" else f'"{c}":%.{DECIMALS}f' for c in names) + "}"
    arrays = [np.asarray(cols[c]).astype(np.int64) if c == "sync" else np.asarray(cols[c], float) for c in names]
    return [(fmt % row).encode() for row in zip(*(a.tolist() for a in arrays), strict=True)]


def write_mcap(path: Path, streams: Sequence[tuple[str, str, Mapping[str, np.ndarray], np.ndarray]]) -> None:
    """One MCAP file: ``streams`` of (topic, schema name, columns, log times in ns) as JSON messages.

    Log times are the recorder's (when each message arrived); messages are written in log-time
    order across channels, as a recorder would.
    """
    from mcap.writer import CompressionType, Writer

    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as fh:
        w = Writer(fh, compression=CompressionType.ZSTD)
        w.start(profile="", library="workbench-virtual-lab")
        merged_t, merged_c, merged_i, payloads = [], [], [], []
        for topic, schema, cols, log_ns in streams:
            sid = w.register_schema(name=schema, encoding="jsonschema", data=_schema(list(cols)))
            cid = w.register_channel(topic=topic, message_encoding="json", schema_id=sid)
            payloads.append(_messages(cols))
            merged_t.append(np.asarray(log_ns, np.int64))
            merged_c.append(np.full(len(log_ns), cid))
            merged_i.append(np.arange(len(log_ns)))
        t, c, i = (np.concatenate(x) for x in (merged_t, merged_c, merged_i))
        order = np.lexsort((i, c, t))
        by_channel = {int(cc[0]): k for k, cc in enumerate(merged_c) if len(cc)}
        for j in order:
            ch = int(c[j])
            seq = int(i[j])
            w.add_message(channel_id=ch, log_time=int(t[j]), data=payloads[by_channel[ch]][seq],
                          publish_time=int(t[j]), sequence=seq)
        w.finish()


def mcap_tunnel_streams(lc: Mapping[str, np.ndarray], lc_log_ns: np.ndarray, motion: Mapping[str, np.ndarray],
                        motion_log_ns: np.ndarray):
    """The two tunnel channels of the contract."""
    return [(MCAP_WRENCH_TOPIC, MCAP_WRENCH_SCHEMA, lc, lc_log_ns),
            (MCAP_JOINT_TOPIC, MCAP_JOINT_SCHEMA, motion, motion_log_ns)]


def mcap_towing_streams(lc: Mapping[str, np.ndarray], lc_log_ns: np.ndarray, carriage: Mapping[str, np.ndarray],
                        carriage_log_ns: np.ndarray):
    """The two towing-tank channels of the contract."""
    return [(MCAP_WRENCH_TOPIC, MCAP_WRENCH_SCHEMA, lc, lc_log_ns),
            (MCAP_CARRIAGE_TOPIC, MCAP_CARRIAGE_SCHEMA, carriage, carriage_log_ns)]


# ------------------------------------------------------------------------ campaign.toml
#: the campaign.toml writer lives in the contract (plan-campaign writes its manifests with it too)
manifest_text = campaign_toml


def loadcell_table(lc: Any, forms: Sequence[str], calibration: Any) -> dict[str, Any]:
    """The manifest's ``[loadcell]`` table; the calibration matrix only when a run is a ``.bin`` capture."""
    table: dict[str, Any] = {"model": lc.model, "rate_hz": float(lc.rate_hz),
                             "full_scale": [float(x) for x in lc.full_scale]}
    if "bin" in forms:
        table["calibration"] = calibration
    return table


def run_files(run_id: str, form: str, partner: str) -> dict[str, str]:
    """A run's file entries: one MCAP, or the load-cell capture plus its ``partner`` log (motion/carriage)."""
    if form == "mcap":
        return {"mcap": f"runs/{run_id}.mcap"}
    return {"loadcell": f"runs/{run_id}.loadcell.{'bin' if form == 'bin' else 'csv'}",
            partner: f"runs/{run_id}.{partner}.csv"}


def write_json(path: Path, obj: Any) -> None:
    """Pretty JSON with keys in the order given and a trailing newline (:func:`workbench.atomic.json_text`).

    A plain write: the generator builds the whole folder in a hidden sibling and swaps it in at once.
    """
    from workbench.atomic import json_text

    path.write_text(json_text(obj), encoding="utf-8")


def write_run(root: Path, run_id: str, form: str, *, recorder: tuple[int, int, str], latency_s: tuple[float, float],
              loadcell: tuple[Mapping[str, np.ndarray], np.ndarray], partner: tuple[str, Mapping[str, np.ndarray],
                                                                                  np.ndarray],
              t0_s: float, mcap_streams: Callable, write_loadcell_bin: Callable[[Path], dict]
              ) -> tuple[dict[str, str], dict[str, Any]]:
    """One run's raw files in its form; returns the manifest's file entries and the truth record's part.

    ``loadcell`` is (columns, controller times of its samples), ``partner`` (name, columns, tick
    times) of the motion or carriage log; ``recorder`` (seed, run index, date) places an MCAP's log
    times (:func:`~workbench.virtual_lab.rig.recorder_log_ns`); ``write_loadcell_bin(path)`` writes a
    ``.bin`` capture and returns its truth record. The tunnel and the towing tank differ only in these.
    """
    from workbench.virtual_lab import rig

    files = run_files(run_id, form, partner[0])
    record: dict[str, Any] = {}
    if form == "mcap":
        seed, index, date = recorder
        rec = rig.recorder_origin_ns(seed, index, date)
        lat = rig.run_rng(seed, index, "mcap")
        lc_ns = rig.recorder_log_ns(rec, loadcell[1], t0_s, lat, latency_s)
        partner_ns = rig.recorder_log_ns(rec, partner[2], t0_s, lat, latency_s)
        write_mcap(root / files["mcap"], mcap_streams(loadcell[0], lc_ns, partner[1], partner_ns))
        record["recorder_origin_ns"] = int(rec)
        return files, record
    write_csv(root / files[partner[0]], partner[1])
    if form == "bin":
        record["bin"] = write_loadcell_bin(root / files["loadcell"])
    else:
        write_csv(root / files["loadcell"], loadcell[0])
    return files, record


# ------------------------------------------------------------------------- the folder
#: marker in truth.json that says the virtual lab wrote the folder (so it may be replaced)
GENERATOR = "workbench.virtual_lab"


def check_target(out_dir: Path, campaign_id: str | None) -> str:
    """The campaign id for ``out_dir`` (its name); refuse to replace a folder the virtual lab did not write."""
    import re

    from workbench.contract.columns import CAMPAIGN_ID_PATTERN
    from workbench.errors import ContractError, OutputError

    cid = out_dir.name if campaign_id is None else campaign_id
    if cid != out_dir.name:
        raise ContractError(f"campaign id {cid!r} differs from the folder name {out_dir.name!r}", path=out_dir,
                            hint="the contract wants id = folder name; name the folder after the campaign")
    if not re.match(CAMPAIGN_ID_PATTERN, cid):
        raise ContractError(f"folder name {cid!r} is not a valid campaign id {CAMPAIGN_ID_PATTERN}", path=out_dir,
                            hint="use lower-case letters, digits, '-' and '_'")
    if out_dir.exists():
        if not out_dir.is_dir():
            raise OutputError("exists and is not a folder", path=out_dir)
        if any(out_dir.iterdir()):
            truth = out_dir / "truth.json"
            try:
                ours = json.loads(truth.read_text(encoding="utf-8")).get("generator") == GENERATOR
            except (OSError, ValueError, AttributeError):
                ours = False
            if not ours:
                raise OutputError("refusing to overwrite a folder the virtual lab did not generate", path=out_dir,
                                  hint="choose a new folder, or move this one away yourself")
    return cid
