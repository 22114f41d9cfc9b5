"""Reader for serial captures (``.bin``): frames found by header and checksum, counts to SI."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.contract.serial import decode_frames
from workbench.errors import ContractError, DataError
from workbench.ingest.readers.base import ReadSpec, read_raw
from workbench.ingest.streams import Stream


class BinReader:
    """A load-cell serial capture: resynchronised frames, unwrapped clock, calibrated wrench."""

    def __init__(self, path: Path, role: str, spec: ReadSpec):
        if role != "loadcell":
            raise ContractError(f"a .bin capture can only be a load-cell log, not the {role} log",
                                path=path, run=spec.run, where=f"field {role}")
        self.path = Path(path)
        self.spec = spec

    def read(self) -> dict[str, Stream]:
        """Decode the capture into the load-cell stream (SI = calibration @ counts)."""
        data, sha = read_raw(self.path, self.spec.run)
        frames = decode_frames(data)
        if len(frames) == 0:
            raise DataError(f"no valid frames in {len(data)} bytes (no AA 55 header with a matching checksum)",
                            path=self.path, run=self.spec.run,
                            hint="is this a load-cell capture at the right baud rate?")
        if self.spec.calibration is None:
            raise ContractError("a .bin capture needs [loadcell] calibration in campaign.toml",
                                path=self.path, run=self.spec.run)
        si = frames.counts.astype(float) @ self.spec.calibration.T
        offsets = frames.offsets

        def locate(i: int) -> str:
            return f"frame {i} (byte {int(offsets[i])})"

        return {"loadcell": Stream(
            role="loadcell", path=self.path, time_s=frames.time_us.astype(float) * 1e-6,
            sync=frames.sync.astype(float), values={c: np.ascontiguousarray(si[:, k]) for k, c in enumerate(WRENCH_CHANNELS)},
            locate=locate, source="bin", sha256=sha, dropped_bytes=frames.dropped_bytes,
            dropped_frames=frames.dropped_frames)}
