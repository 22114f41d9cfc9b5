"""The optimiser's gaits as one vectorised batch (paper section IV, table II): B gaits, four legs each.

A :class:`GaitBatch` holds the parameters of B gaits as arrays, so a whole NSGA-II population is
one object (pymoo's vectorised Problem evaluates it at once): the paper's joint sinusoid
(equation 3) for all 4B legs, sub-batches, mirror images, and the gait files' ``params`` dicts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Mapping, Sequence

import numpy as np

from workbench.errors import SettingError
from workbench.hydro.motion import JointSinusoid, LegMotion

#: the paper's fixed gait constants (section IV): theta_h_max, theta_k_min, phi
THETA_H_MAX_DEG = -100.0
THETA_K_MIN_DEG = 80.0
PHI_RAD = math.pi / 3


@dataclass(frozen=True)
class GaitBatch:
    """B gaits for the four legs (LF, RF, LH, RH), the optimiser's parameters (paper table II).

    ``theta_h_min_deg`` and ``theta_k_max_deg`` are ``(B, 4)`` (the paper uses one value for all
    legs; per-leg values are allowed), ``frequency_hz`` is ``(B,)``, ``alpha_rad`` ``(B, 4)``.
    """

    theta_h_min_deg: np.ndarray
    theta_k_max_deg: np.ndarray
    frequency_hz: np.ndarray
    alpha_rad: np.ndarray
    theta_h_max_deg: float = THETA_H_MAX_DEG
    theta_k_min_deg: float = THETA_K_MIN_DEG
    phi_rad: float = PHI_RAD

    @classmethod
    def from_arrays(cls, theta_h_min_deg, theta_k_max_deg, frequency_hz, alpha_rad, **fixed) -> "GaitBatch":
        """Broadcast per-gait (B,) or per-leg (B, 4) values; scalars make a batch of one.

        Values that are not numbers, or shapes that do not broadcast, are a :class:`SettingError`.
        """
        def legs(x):
            x = np.asarray(x, float)
            if x.ndim <= 1:
                x = np.reshape(x, (-1, 1))
            return np.ascontiguousarray(np.broadcast_to(x, (b, 4)), dtype=float)

        try:
            alpha = np.atleast_2d(np.asarray(alpha_rad, float))
            b = max(alpha.shape[0], np.size(frequency_hz), np.atleast_1d(theta_h_min_deg).shape[0],
                    np.atleast_1d(theta_k_max_deg).shape[0])
            freq = np.ascontiguousarray(np.broadcast_to(np.asarray(frequency_hz, float).reshape(-1), (b,)))
            gaits = cls(legs(theta_h_min_deg), legs(theta_k_max_deg), freq, legs(alpha), **fixed)
        except (TypeError, ValueError) as exc:  # numpy's words for a string, a mapping or a ragged list
            raise SettingError(f"gait parameters must be numbers (one per gait, or four per gait for the "
                               f"legs): {exc}") from None
        if np.any(gaits.frequency_hz <= 0) or not all(np.all(np.isfinite(a)) for a in gaits._arrays()):
            raise SettingError("gait parameters must be finite with positive frequency")
        return gaits

    @classmethod
    def from_params(cls, params: Sequence[Mapping], labels: Sequence[str] | None = None, **fixed) -> "GaitBatch":
        """From gait-file ``params`` dicts (data contract section 5).

        A missing or bad value is a :class:`SettingError`; with ``labels`` (one per gait) its ``where``
        names the first gait at fault, so a caller can add the file: ``exc.located(path=...)``.
        """
        try:
            return cls._from_params(params, **fixed)
        except SettingError as exc:
            if labels is None:
                raise
            for label, p in zip(labels, params, strict=True):
                try:
                    cls._from_params([p], **fixed)
                except SettingError as one:
                    raise one.located(where=label) from None
            raise exc.located(where=", ".join(labels)) from None

    @classmethod
    def _from_params(cls, params: Sequence[Mapping], **fixed) -> "GaitBatch":
        try:
            return cls.from_arrays(
                [p["theta_h_min_deg"] for p in params], [p["theta_k_max_deg"] for p in params],
                [p["frequency_hz"] for p in params],
                [p["alpha_rad"] if np.ndim(p["alpha_rad"]) else [p["alpha_rad"]] * 4 for p in params], **fixed)
        except KeyError as exc:
            raise SettingError(f"gait parameters lack {exc}") from None
        except TypeError:  # a list or a number where the params table should be
            raise SettingError("gait parameters must be a table of theta_h_min_deg, theta_k_max_deg, "
                               "frequency_hz and alpha_rad") from None

    def _arrays(self):
        return (self.theta_h_min_deg, self.theta_k_max_deg, self.frequency_hz, self.alpha_rad)

    def __len__(self) -> int:
        return int(self.frequency_hz.shape[0])

    def rows(self, idx) -> "GaitBatch":
        """A sub-batch (index, slice or mask)."""
        idx = np.atleast_1d(np.arange(len(self))[idx])
        return replace(self, theta_h_min_deg=self.theta_h_min_deg[idx], theta_k_max_deg=self.theta_k_max_deg[idx],
                       frequency_hz=self.frequency_hz[idx], alpha_rad=self.alpha_rad[idx])

    def mirrored(self) -> "GaitBatch":
        """The mirror-image gaits: left and right legs swap their parameters."""
        swap = [1, 0, 3, 2]
        return replace(self, theta_h_min_deg=self.theta_h_min_deg[:, swap],
                       theta_k_max_deg=self.theta_k_max_deg[:, swap], alpha_rad=self.alpha_rad[:, swap])

    def sinusoid(self) -> JointSinusoid:
        """The paper's equation 3 with array parameters broadcasting to (B, 4, T)."""
        return JointSinusoid(self.theta_h_min_deg[..., None], self.theta_h_max_deg, self.theta_k_min_deg,
                             self.theta_k_max_deg[..., None], self.frequency_hz[:, None, None], self.phi_rad,
                             self.alpha_rad[..., None])

    def leg_motion(self, t_s: np.ndarray) -> LegMotion:
        """All 4B legs' joint histories (rows ordered gait-major: b * 4 + leg), analytic rates, no flow."""
        t = np.asarray(t_s, float)
        th, tk, wh, wk, ah, ak = (np.broadcast_to(x, (len(self), 4, t.size)).reshape(4 * len(self), t.size)
                                  for x in self.sinusoid().evaluate(t))
        dt = float(t[1] - t[0]) if t.size > 1 else 1.0
        return LegMotion(dt, th, tk, wh, wk, np.zeros_like(th), ah, ak)

    def to_params(self) -> list[dict]:
        """Gait-file ``params`` dicts (contract names; scalars where all legs agree)."""
        out = []
        for i in range(len(self)):
            row = {}
            for name, arr in (("theta_h_min_deg", self.theta_h_min_deg), ("theta_k_max_deg", self.theta_k_max_deg)):
                vals = arr[i]
                row[name] = float(vals[0]) if np.all(vals == vals[0]) else [float(v) for v in vals]
            row["frequency_hz"] = float(self.frequency_hz[i])
            row["alpha_rad"] = [float(a) for a in self.alpha_rad[i]]
            out.append(row)
        return out
