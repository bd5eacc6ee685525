"""What a lab knows about its turntable's pointing error: the prior of the nine black-box angles.

The nine angles (docs/explanation/model.md#attitude-chain; rows outer base `C_t^o0`, middle `C_o^m0`, inner
`C_m^i0`; columns alpha, beta, gamma) get a second-moment matrix `E[theta theta^T]`
(rad^2) from one of:

- a **datasheet figure**, `[table] pointing_accuracy_arcsec`: the 1-sigma (RMS) of every
  angle, or per frame (`{outer, middle, inner}`: that frame's three angles); with
  `orthogonality_arcsec` the alphas and betas (axis tilts) take that figure and the
  gammas (zero offsets about each frame's own axis) the pointing figure;
- a **table-check result** (`bench check-table`, `[table] check = FILE`): it measures four
  combinations `c = A theta` with covariance `S`; with the stated prior `P` for every
  angle (the datasheet figure, else `UNSEEN_PRIOR_ARCSEC`), the second moment of theta
  given the check is `Q + mu mu^T` with `mu = P A^T (A P A^T + S)^-1 c` and
  `Q = P - P A^T (A P A^T + S)^-1 A P`: what the check measured enters with its value
  and sigma, what it cannot see (the gammas, the split of the middle/inner sums) keeps
  the prior.

The budget (`bench.solve.budget`) propagates it through the plan's solve.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bench.errors import InputError
from bench.files import parse_json, read_input_text
from bench.model.units import ARCSEC

#: the table check's result format (`bench check-table`)
CHECK_FORMAT = "turntable-bench/table-check"
#: the angles in the check's names, in black-box order (o0, m0, i0 x alpha, beta, gamma)
CHECK_ANGLE_NAMES = ("alpha_o", "beta_o", "gamma_o", "alpha_m", "beta_m", "gamma_m", "alpha_i", "beta_i", "gamma_i")
#: the prior of the angles a table check cannot see when no datasheet figure is configured (arcsec)
UNSEEN_PRIOR_ARCSEC = 20.0
FRAME_KEYS = ("outer", "middle", "inner")


class TablePriorError(InputError):
    """A table-check file that cannot serve as the table's prior."""


@dataclass(frozen=True)
class TablePrior:
    """Second moment (9, 9) of the nine black-box angles (rad^2), and where it came from."""

    covariance_rad2: np.ndarray
    source: str

    def __post_init__(self) -> None:
        cov = np.asarray(self.covariance_rad2, dtype=float)
        if cov.shape != (9, 9) or not np.all(np.isfinite(cov)) or np.any(np.diag(cov) < 0):
            raise ValueError("the table's angle covariance must be a finite 9x9 matrix")
        object.__setattr__(self, "covariance_rad2", 0.5 * (cov + cov.T))

    @classmethod
    def from_sigmas(cls, sigma_rad, source: str) -> "TablePrior":
        return cls(np.diag(np.asarray(sigma_rad, dtype=float).reshape(9) ** 2), source)

    @classmethod
    def uniform(cls, arcsec: float, source: str) -> "TablePrior":
        return cls.from_sigmas(np.full(9, arcsec * ARCSEC), source)

    @property
    def sigma_rad(self) -> np.ndarray:
        """(3, 3) the 1-sigma (root second moment) of each angle."""
        return np.sqrt(np.diag(self.covariance_rad2)).reshape(3, 3)

    def to_json(self) -> dict[str, Any]:
        return {"source": self.source, "sigma_arcsec": (self.sigma_rad / ARCSEC).round(6).tolist()}


def pointing_sigmas_arcsec(pointing: float | dict[str, float], orthogonality: float | None) -> np.ndarray:
    """(3, 3) arcsec per angle from a datasheet pointing figure (overall or per frame) and orthogonality."""
    per_frame = [pointing[f] for f in FRAME_KEYS] if isinstance(pointing, dict) else [float(pointing)] * 3
    out = np.array([[p, p, p] for p in per_frame], dtype=float)
    if orthogonality is not None:
        out[:, :2] = orthogonality
    return out


def from_datasheet(pointing: float | dict[str, float], orthogonality: float | None = None) -> TablePrior:
    sig = pointing_sigmas_arcsec(pointing, orthogonality)
    what = (f"{pointing:g} arcsec" if not isinstance(pointing, dict)
            else ", ".join(f"{f} {pointing[f]:g}" for f in FRAME_KEYS) + " arcsec")
    if orthogonality is not None:
        what += f", orthogonality {orthogonality:g} arcsec"
    return TablePrior.from_sigmas(sig * ARCSEC, f"datasheet: pointing accuracy {what} (1-sigma)")


#: the largest |value| or sigma of a table-check combination, arcsec, and |coefficient| of an angle in one
MAX_CHECK_ARCSEC = 1e6
MAX_CHECK_COEFFICIENT = 1e3


def from_check(data: Any, prior_sigma_arcsec: np.ndarray | None, origin: str) -> TablePrior:
    """The prior given a table-check result (its JSON) and the stated prior of every angle (3, 3 arcsec)."""
    if not isinstance(data, dict) or data.get("format") != CHECK_FORMAT:
        raise TablePriorError(f"{origin}: not a {CHECK_FORMAT} file (from `bench check-table`)")
    try:
        combos = data["combinations"]
        rows, values, sigmas = [], [], []
        for c in combos:
            row = np.zeros(9)
            for name, coef in c["coefficients"].items():
                row[CHECK_ANGLE_NAMES.index(name)] = float(coef)
            rows.append(row)
            values.append(float(c["value_arcsec"]))
            sigmas.append(float(c["sigma_arcsec"]))
        corr = np.array(data.get("correlation") or np.eye(len(rows)), dtype=float)
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise TablePriorError(f"{origin}: its combinations need coefficients, value_arcsec and sigma_arcsec "
                              f"({exc})") from exc
    a = np.array(rows)
    v = np.array(values) * ARCSEC
    s = np.array(sigmas) * ARCSEC
    if not rows or corr.shape != (len(rows), len(rows)) or not (np.all(np.isfinite(v)) and np.all(s >= 0)
                                                                and np.all(np.isfinite(corr))):
        raise TablePriorError(f"{origin}: combinations, sigmas or correlation are missing or not finite")
    # a check measures angles of arcseconds: values far beyond make the covariance overflow
    if (np.abs(a).max() > MAX_CHECK_COEFFICIENT or np.abs(np.array(values)).max() > MAX_CHECK_ARCSEC
            or max(sigmas) > MAX_CHECK_ARCSEC or np.abs(corr).max() > 1.0):
        raise TablePriorError(f"{origin}: a coefficient beyond {MAX_CHECK_COEFFICIENT:g}, a value or sigma beyond "
                              f"{MAX_CHECK_ARCSEC:g} arcsec, or a correlation beyond 1")
    stated = prior_sigma_arcsec is not None
    prior = (np.asarray(prior_sigma_arcsec, dtype=float).reshape(9) if stated
             else np.full(9, UNSEEN_PRIOR_ARCSEC)) * ARCSEC
    p = np.diag(prior ** 2)
    s_cov = corr * np.outer(s, s)
    try:
        gain = p @ a.T @ np.linalg.inv(a @ p @ a.T + s_cov)
    except np.linalg.LinAlgError as exc:
        raise TablePriorError(f"{origin}: its combinations cannot be combined (singular: {exc})") from None
    mu = gain @ v
    q = p - gain @ a @ p
    if not np.all(np.isfinite(q + np.outer(mu, mu))):
        raise TablePriorError(f"{origin}: its combinations give no finite angle covariance")
    unseen = ("the datasheet figure" if stated else f"a stated prior of {UNSEEN_PRIOR_ARCSEC:g} arcsec "
              "(no [table] pointing_accuracy_arcsec)")
    return TablePrior(q + np.outer(mu, mu), f"table check {Path(origin).name}: {len(rows)} measured combinations; "
                                             f"the angles it cannot see take {unseen}")


def load_check(path: str | Path, prior_sigma_arcsec: np.ndarray | None) -> TablePrior:
    """`from_check` of a table-check file (TablePriorError: unreadable or not a check)."""
    try:
        data = parse_json(read_input_text(path, what="table-check file"), str(path))
    except OSError as exc:
        raise TablePriorError(f"{path}: cannot read: {exc.strerror or exc}") from exc
    except InputError as exc:   # not a regular file, too large, not JSON, a number out of range
        raise TablePriorError(str(exc)) from None
    return from_check(data, prior_sigma_arcsec, str(path))


def rms_arcsec(black_box_rad) -> float:
    """RMS of nine black-box angles, arcsec."""
    bb = np.asarray(black_box_rad, dtype=float)
    return math.sqrt(float(np.mean(bb ** 2))) / ARCSEC


__all__ = ["CHECK_ANGLE_NAMES", "CHECK_FORMAT", "FRAME_KEYS", "TablePrior", "TablePriorError", "UNSEEN_PRIOR_ARCSEC",
           "from_check", "from_datasheet", "load_check", "pointing_sigmas_arcsec", "rms_arcsec"]
