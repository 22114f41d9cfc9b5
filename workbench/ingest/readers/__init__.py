"""One reader per raw source behind one protocol; :func:`make_reader` picks it by the file's kind.

Like ``mcap.reader.make_reader``, the caller names the file and gets the right implementation:
``.csv`` -> :class:`CsvReader`, ``.bin`` -> :class:`BinReader`, ``.mcap`` -> :class:`McapReader`.
:func:`read_run` reads all files of a run and returns its streams keyed by role.
"""

from __future__ import annotations

from pathlib import Path

from workbench.contract.campaign import Campaign, RunSpec
from workbench.errors import ContractError
from workbench.ingest.readers.base import RawReader, ReadSpec, read_raw
from workbench.ingest.readers.bin_reader import BinReader
from workbench.ingest.readers.csv_reader import CsvReader
from workbench.ingest.readers.mcap_reader import McapReader
from workbench.ingest.streams import Stream

READERS = {".csv": CsvReader, ".bin": BinReader, ".mcap": McapReader}

__all__ = ["BinReader", "CsvReader", "McapReader", "RawReader", "ReadSpec", "make_reader", "read_raw", "read_run"]


def make_reader(path: str | Path, role: str, spec: ReadSpec) -> RawReader:
    """The reader for one raw file of a run, chosen by its suffix (``role``: the manifest key)."""
    path = Path(path)
    cls = READERS.get(path.suffix.lower())
    if cls is None or (role == "mcap") != (cls is McapReader):
        allowed = ".mcap" if role == "mcap" else (".csv or .bin" if role == "loadcell" else ".csv")
        raise ContractError(f"'{role}' file must be {allowed}, got {path.suffix or 'no suffix'!r}",
                            path=path, run=spec.run, where=f"field {role}")
    return cls(path, role, spec)


def read_run(campaign: Campaign, run: RunSpec) -> dict[str, Stream]:
    """Read every file of a run: the load-cell stream and the controller stream, keyed by role."""
    spec = ReadSpec.for_run(campaign, run.id)
    if run.mcap is not None:
        return make_reader(run.mcap, "mcap", spec).read()
    streams: dict[str, Stream] = {}
    for role in ("loadcell", spec.controller_role):
        path = getattr(run, role)
        if path is None:
            raise ContractError(f"missing '{role}' file (or 'mcap')", path=campaign.manifest, run=run.id)
        streams.update(make_reader(path, role, spec).read())
    return streams
