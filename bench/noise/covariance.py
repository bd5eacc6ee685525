"""The covariance of overlapping Allan variance estimates at different cluster times, from a noise model.

Neighbouring points of an Allan curve are far from independent (octave-spaced overlapping
estimates correlate by 0.5-0.8 on simulated data), so a fit that treats them as
independent claims uncertainties several times too small. For a Gaussian noise model
the covariance is exact to compute: with x the phase (the integrated rate) and each
noise process given by its generalised covariance G(t) (so that for coefficient
vectors a, b that annihilate constants and lines, cov(sum a_i x(t_i), sum b_j x(s_j)) =
sum a_i b_j G(s_j - t_i)), the normalised second differences

    Z_m(k) = (x[k+2m] - 2 x[k+m] + x[k]) / (sqrt(2) m tau0),   AVAR_m = E Z_m^2,

have cross-covariances C_mn(d) = E[Z_m(k) Z_n(k+d)], and the estimates (means of Z^2
over L_m = N - 2m terms) covary as

    cov(AVAR_m, AVAR_n) ~= 2 sum_d C_mn(d)^2 / max(L_m, L_n)

(Isserlis' theorem). The processes and their G (AVAR contribution in brackets):

- white PM, phase variance q^2 (3 q^2 / tau^2):   x white: C from the coincident samples;
- white FM, N (N^2 / tau):                        G = -N^2 |t| / 2;
- flicker FM, constant AVAR A (A):                G = A t^2 ln|t| / (4 ln 2);
- random walk FM, K (K^2 tau / 3):                G = K^2 |t|^3 / 12;
- first-order Gauss-Markov rate, sigma s, time T: G = -s^2 T^2 (|t|/T - 1 + exp(-|t|/T)).

C_mn(d) vanishes beyond |d| = 2(m + n) for all but flicker and Gauss-Markov (a fourth
difference of a cubic; those two decay, and are summed to there too); the sum over d is
exact for short clusters and a trapezoid over 1,201 lags beyond.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

#: Model terms in the order of their coefficients: AVAR = sum c_p basis_p(tau).
TERMS = ("white_pm", "white_fm", "flicker_fm", "random_walk_fm", "gauss_markov")
_LAGS = 1201          # lag samples per pair beyond the exact range
_COEF_A = np.array([1.0, -2.0, 1.0])


def gauss_markov_avar(tau_s: np.ndarray, sigma: float, correlation_time_s: float) -> np.ndarray:
    """Allan variance of a first-order Gauss-Markov process (same unit^2 as sigma^2)."""
    x = np.asarray(tau_s, dtype=float) / correlation_time_s
    # Series for small x avoids cancellation: 2x - 3 + 4e^-x - e^-2x = 2/3 x^3 - 1/2 x^4 + 7/30 x^5 - ...
    small = x < 1e-3
    bracket = np.where(small, (2.0 / 3.0) * x ** 3 - 0.5 * x ** 4 + (7.0 / 30.0) * x ** 5,
                       2.0 * x - 3.0 + 4.0 * np.exp(-x) - np.exp(-2.0 * x))
    return sigma ** 2 * bracket / np.maximum(x, 1e-300) ** 2


def basis(tau_s: np.ndarray, correlation_time_s: float | None) -> np.ndarray:
    """(len(tau), 5) AVAR per unit coefficient: 1/tau^2, 1/tau, 1, tau, Gauss-Markov per unit variance (0 if None)."""
    tau = np.asarray(tau_s, dtype=float)
    out = np.column_stack([1.0 / tau ** 2, 1.0 / tau, np.ones_like(tau), tau, np.zeros_like(tau)])
    if correlation_time_s is not None:
        out[:, 4] = gauss_markov_avar(tau, 1.0, correlation_time_s)
    return out


def _generalised(t: np.ndarray, correlation_time_s: float | None) -> np.ndarray:
    """(5, *t.shape) G of each term per unit coefficient (white PM handled apart: 0 here; Gauss-Markov only with
    a correlation time)."""
    a = np.abs(t)
    out = np.zeros((5,) + t.shape)
    if correlation_time_s is not None:
        T = correlation_time_s
        out[4] = -T * T * (a / T - 1.0 + np.exp(-a / T))
        return out
    out[1] = -a / 2.0                                       # N^2 / tau  <-  G = -c |t| / 2
    with np.errstate(divide="ignore", invalid="ignore"):
        out[2] = np.where(a > 0, t * t * np.log(np.where(a > 0, a, 1.0)), 0.0) / (4.0 * math.log(2.0))
    out[3] = a ** 3 / 4.0                                   # c tau  <-  G = c |t|^3 / 4 (c = K^2 / 3)
    return out


def _cross(m: int, n: int, lags: np.ndarray, tau0: float, correlation_time_s: float | None) -> np.ndarray:
    """(5, len(lags)) C_mn at lag samples `lags` per unit coefficient: white PM, white FM, flicker and random walk
    without a correlation time; the Gauss-Markov row alone with one."""
    tm = np.array([0.0, m, 2.0 * m])
    tn = np.array([0.0, n, 2.0 * n])
    weights = np.outer(_COEF_A, _COEF_A)                     # a_i b_j
    offsets = (tn[None, :] - tm[:, None])                   # t = (d + t_j - t_i) tau0 for every lag and (i, j)
    t = (lags[:, None, None] + offsets[None]) * tau0         # (L, 3, 3)
    g = _generalised(t, correlation_time_s)                  # (5, L, 3, 3)
    c = np.einsum("plij,ij->pl", g, weights)
    if correlation_time_s is None:
        # white PM: x white, E[x_a x_b] = q^2 [a == b]; q^2 = coefficient / 3 (AVAR 3 q^2 / tau^2)
        coincide = (np.abs(t / tau0) < 0.5)                  # only at integer lags
        c[0] = np.einsum("lij,ij->l", coincide.astype(float), weights) / 3.0
    return c / (2.0 * m * n * tau0 * tau0)


def _cross_gauss_markov(m: int, n: int, lags: np.ndarray, tau0: float, correlation_time_s: float) -> np.ndarray:
    """C_mn of a unit-variance Gauss-Markov rate at lag samples `lags`."""
    offsets = (np.array([0.0, n, 2.0 * n])[None, :] - np.array([0.0, m, 2.0 * m])[:, None]).reshape(-1)
    a = np.abs(lags[:, None] + offsets[None, :]) * (tau0 / correlation_time_s)     # (L, 9) |t| / T
    g = (a - 1.0 + np.exp(-a)) @ np.outer(_COEF_A, _COEF_A).reshape(-1)
    return -correlation_time_s ** 2 * g / (2.0 * m * n * tau0 * tau0)


def _lags(mi: int, mj: int) -> tuple[np.ndarray, np.ndarray, bool]:
    """The lags summed over for a pair of sizes, their weights, and whether they are every integer lag."""
    reach = 2 * (mi + mj)
    if 2 * reach + 1 <= _LAGS:
        lags = np.arange(-reach, reach + 1, dtype=float)
        return lags, np.ones(len(lags)), True
    lags = np.linspace(-reach, reach, _LAGS)                # a trapezoid over a fine grid of lags
    w = np.full(len(lags), lags[1] - lags[0])
    w[[0, -1]] *= 0.5
    return lags, w, False


@lru_cache(maxsize=4096)
def _pair_fixed(mi: int, mj: int, tau0: float) -> np.ndarray:
    """(5, L) C_mn of the terms without a correlation time (the Gauss-Markov row 0)."""
    lags, _, exact = _lags(mi, mj)
    c = _cross(mi, mj, lags, tau0, None)
    if not exact:
        c[0] = 0.0        # white PM's coincident samples fall between grid lags: negligible at such m
    return c


def cross_terms(m: np.ndarray, n_phase: int, tau0: float, correlation_time_s: float | None) -> np.ndarray:
    """(k, k, 5, 5) S[i, j, p, q] with cov(AVAR_i, AVAR_j) = sum_pq c_p c_q S[i, j, p, q] (see module doc).

    The sum over lags stops at 2 (m + n): beyond, every term but flicker and Gauss-Markov is exactly 0, and
    those decay (as 1 / d^2, and as exp(-d tau0 / T) times a fourth difference)."""
    sizes = [int(v) for v in m]
    k = len(sizes)
    out = np.zeros((k, k, 5, 5))
    for i in range(k):
        for j in range(i, k):
            mi, mj = sizes[i], sizes[j]
            lags, w, _ = _lags(mi, mj)
            c = _pair_fixed(mi, mj, tau0)
            if correlation_time_s is not None:
                c = c.copy()
                c[4] = _cross_gauss_markov(mi, mj, lags, tau0, correlation_time_s)
            s = np.einsum("pl,ql,l->pq", c, c, w) * 2.0 / max(n_phase - 2 * mi, n_phase - 2 * mj, 1)
            out[i, j] = out[j, i] = s
    return out


def avar_covariance(cross: np.ndarray, coefficients: np.ndarray) -> np.ndarray:
    """(k, k) covariance of the AVAR estimates for model coefficients (5,)."""
    return np.einsum("ijpq,p,q->ij", cross, coefficients, coefficients)


__all__ = ["TERMS", "avar_covariance", "basis", "cross_terms", "gauss_markov_avar"]
