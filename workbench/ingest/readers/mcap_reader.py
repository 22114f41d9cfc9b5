"""Reader for MCAP run files: JSON messages on the contract's topics, parsed in bulk by polars.

The message fields are the CSV columns; ``time_s`` carries the device clocks. MCAP log times are
the recorder's and are ignored: messages are taken in file order, the order they were recorded.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import polars as pl
from mcap.reader import make_reader

from workbench.contract.columns import (
    MCAP_CARRIAGE_SCHEMA,
    MCAP_CARRIAGE_TOPIC,
    MCAP_JOINT_SCHEMA,
    MCAP_JOINT_TOPIC,
    MCAP_WRENCH_SCHEMA,
    MCAP_WRENCH_TOPIC,
)
from workbench.errors import ContractError, DataError
from workbench.ingest.readers.base import ReadSpec, header_fault, read_raw
from workbench.ingest.streams import Stream

#: role -> (topic, schema name)
TOPICS = {
    "loadcell": (MCAP_WRENCH_TOPIC, MCAP_WRENCH_SCHEMA),
    "motion": (MCAP_JOINT_TOPIC, MCAP_JOINT_SCHEMA),
    "carriage": (MCAP_CARRIAGE_TOPIC, MCAP_CARRIAGE_SCHEMA),
}


class McapReader:
    """One run's MCAP file: the load-cell stream and the controller stream (motion or carriage)."""

    def __init__(self, path: Path, role: str, spec: ReadSpec):
        self.path = Path(path)
        self.spec = spec
        self.roles = ("loadcell", spec.controller_role)

    def _fail(self, cls, fault, where=None, hint=None):
        raise cls(fault, path=self.path, run=self.spec.run, where=where, hint=hint)

    def read(self) -> dict[str, Stream]:
        """Parse both streams of the run."""
        data, sha = read_raw(self.path, self.spec.run)
        wanted = {TOPICS[r][0]: r for r in self.roles}
        messages: dict[str, list[bytes]] = {t: [] for t in wanted}
        channels: dict[str, tuple[str | None, str]] = {}
        try:
            reader = make_reader(io.BytesIO(data), validate_crcs=True)
            counts: dict[int, int] = {}
            for schema, channel, message in reader.iter_messages(topics=list(wanted), log_time_order=False):
                messages[channel.topic].append(message.data)
                channels[channel.topic] = (schema.name if schema else None, channel.message_encoding)
                counts[channel.id] = counts.get(channel.id, 0) + 1
            summary = reader.get_summary()
        except Exception as exc:  # the mcap library raises many kinds on damaged files
            self._fail(DataError, f"corrupt MCAP: {type(exc).__name__}: {exc}".splitlines()[0][:200],
                       hint="the recording may be truncated or damaged; re-export it")
        # a damaged chunk can be skipped silently by the reader: check against the file's statistics
        if summary is not None and summary.statistics is not None:
            for cid, ch in summary.channels.items():
                expected = summary.statistics.channel_message_counts.get(cid, 0)
                if ch.topic in wanted and counts.get(cid, 0) != expected:
                    self._fail(DataError, f"corrupt MCAP: read {counts.get(cid, 0)} of the {expected} messages "
                               f"the file lists on {ch.topic}", hint="a chunk is damaged; re-export the recording")
        out = {}
        for topic, role in wanted.items():
            out[role] = self._stream(role, topic, messages[topic], channels.get(topic), sha)
        return out

    def _stream(self, role: str, topic: str, msgs: list[bytes], channel, sha: str) -> Stream:
        if not msgs:
            self._fail(ContractError, f"no messages on {topic}", hint=f"a {self.spec.facility} run records "
                       f"{' and '.join(TOPICS[r][0] for r in self.roles)}")
        schema_name, encoding = channel
        if encoding != "json":
            self._fail(ContractError, f"{topic} uses message encoding {encoding!r}; the contract uses 'json'")
        if schema_name != TOPICS[role][1]:
            self._fail(ContractError, f"{topic} has schema {schema_name!r}; the contract names it {TOPICS[role][1]!r}")
        expected = self.spec.columns(role)
        first = self._decode(msgs[0], topic, 0)
        fault = header_fault(sorted(first), tuple(sorted(expected)), "field")
        if fault:
            self._fail(ContractError, fault.split("; expected")[0], f"message 1 on {topic}")
        try:
            df = pl.read_ndjson(io.BytesIO(b"\n".join(msgs)), schema={c: pl.Float64 for c in expected})
        except Exception as exc:
            self._diagnose(msgs, expected, topic)
            self._fail(DataError, f"cannot parse messages on {topic}: {str(exc).splitlines()[0][:160]}")
        if df.null_count().sum_horizontal().item():
            self._diagnose(msgs, expected, topic)
        arrays = {c: df.get_column(c).to_numpy() for c in expected}

        def locate(i: int) -> str:
            return f"message {i + 1} on {topic}"

        sync = arrays["sync"]
        return Stream(role=role, path=self.path, time_s=arrays["time_s"], sync=np.where(np.isfinite(sync), sync, -1.0),
                      values={c: arrays[c] for c in expected if c not in ("time_s", "sync")}, locate=locate,
                      source="mcap", sha256=sha)

    def _decode(self, raw: bytes, topic: str, i: int) -> dict:
        try:
            obj = json.loads(raw)
        except (ValueError, UnicodeDecodeError):
            self._fail(DataError, "message is not valid JSON", f"message {i + 1} on {topic}")
        if not isinstance(obj, dict):
            self._fail(ContractError, "message is not a JSON object", f"message {i + 1} on {topic}")
        return obj

    def _diagnose(self, msgs: list[bytes], expected: tuple[str, ...], topic: str) -> None:
        """Find the first message with missing, extra or non-numeric fields (slow path, bad files only)."""
        for i, raw in enumerate(msgs):
            obj = self._decode(raw, topic, i)
            fault = header_fault(sorted(obj), tuple(sorted(expected)), "field")
            if fault:
                self._fail(ContractError, fault.split("; expected")[0], f"message {i + 1} on {topic}")
            for name in expected:
                v = obj[name]
                if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))):
                    self._fail(ContractError, f"non-numeric value {v!r} in field {name}", f"message {i + 1} on {topic}")
