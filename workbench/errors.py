"""One exception root for the workbench; each subclass formats a message naming file, run and fault."""

from __future__ import annotations

from pathlib import Path


class WorkbenchError(Exception):
    """Root of every error the workbench raises on bad input or a failed step.

    The message is one line: where (file, run, line or field), what is wrong, and,
    when useful, what to do about it. The CLI prints it as ``error: <message>`` and
    exits with status 2.
    """

    def __init__(self, fault: str, *, path: str | Path | None = None, run: str | None = None,
                 where: str | None = None, hint: str | None = None):
        self.fault = fault
        self.path = None if path is None else str(path)
        self.run = run
        self.where = where
        self.hint = hint
        super().__init__(self.format())

    def format(self) -> str:
        """Return the one-line message: ``file [run r] [where]: fault (hint)``."""
        head = []
        if self.path:
            head.append(self.path)
        if self.run:
            head.append(f"run {self.run}")
        if self.where:
            head.append(self.where)
        msg = (": ".join([", ".join(head), self.fault]) if head else self.fault)
        if self.hint:
            msg += f" ({self.hint})"
        return " ".join(msg.split())

    def located(self, *, path: str | Path | None = None, run: str | None = None,
                where: str | None = None) -> "WorkbenchError":
        """The same error (same class, fault and hint) with the place it lacked filled in.

        For the caller that knows the file a domain check did not (a command re-raising a
        :class:`SettingError` from the simulator with its gaits file): fields already set are kept,
        so the place the fault was found wins. ``raise exc.located(path=p) from None``.
        """
        new = type(self).__new__(type(self))
        new.__dict__.update(self.__dict__)
        new.path = self.path or (None if path is None else str(path))
        new.run = self.run or run
        new.where = self.where or where
        new.args = (new.format(),)
        return new


class ContractError(WorkbenchError):
    """A file or folder breaks the data contract (manifest, columns, paths, schema version)."""


class OutputError(ContractError):
    """An output cannot be written as asked: it would replace what the verb did not write, or lies in raw data."""


class DataError(WorkbenchError):
    """A file follows the contract's shape but its data is unusable (NaN, gaps, no frames, ...)."""


class CampaignRefused(WorkbenchError):
    """A campaign has one or more bad runs and was refused as a whole; ``errors`` lists each one."""

    def __init__(self, campaign: str | Path, errors: list[WorkbenchError]):
        self.errors = errors
        runs = ", ".join(e.run or "?" for e in errors)
        super().__init__(
            f"{len(errors)} bad run(s): {runs}; first: {errors[0].format()}",
            path=campaign,
            hint="fix them or pass --skip-bad-runs to ingest the rest",
        )


class ParamsError(WorkbenchError):
    """A parameter file (pipelines/*.yaml or a --params file) is unusable.

    Missing, not YAML, a section that is not there, an unknown key (``where`` is its key path, e.g. ``diagnose.fit.surrogate_serch``;
    the hint names the nearest allowed key and all of them), a value of the wrong type or out of range.
    """

    @property
    def key(self) -> str | None:
        """The key path of the offending setting (``diagnose.fit.surrogate_search``), when known."""
        return self.where


class SettingError(ParamsError, ValueError):
    """A setting's value is wrong (out of range, not one of the choices, inconsistent with another).

    Raised where the value is checked (a settings class's ``__post_init__``, the domain function that
    takes it), usually before the file is known: the loader that read the file adds it
    (:func:`workbench.params.build` fills ``path`` and the key). Also a ``ValueError``, so callers written
    for the ``ValueError`` these checks raised before keep catching it.
    """


class ConvergenceError(WorkbenchError):
    """A numerical solver did not converge: what it produced is not a result (a fit, a flow field, a solve)."""


class ModelError(WorkbenchError):
    """A model cannot be found, loaded or applied."""


class ModelLoadError(ModelError):
    """A model's files or registry entry cannot be read: missing, corrupt, or from an incompatible version."""


class StageError(WorkbenchError):
    """A pipeline stage failed; its previous outputs are left as they were."""
