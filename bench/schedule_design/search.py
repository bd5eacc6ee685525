"""Exhaustive search of inner-symmetric 24-position schedules and paired 6-rotation sets.

Everything is first order at a zero black box with an ideal IMU (unit scale, orthogonal
axes, no bias), in which case the least-squares parameters of sensor c are
`p_c = e_c`, `q_c = 0` and their first-order changes are exactly the coefficient
sensitivities (Ka/Kg relative = dp_c[c], Ea/Eg = dp_c[a], K0 in g = dq_c). A real
IMU's sensitivities are a linear map of these, so a zero here is a zero there.

Positions: per position k with design row `a_k = [f_k / g, 1]` (integers for positive
positions) and derivative `dy_k[c, j] = (dC_t^b/dtheta_j e_U)[c]` (integers), the fit's
first-order change is `dP = N^-1 S` with `N = sum a a^T` and `S = sum a (x) dy`, both
ADDITIVE over positions, hence over groups. The gyro bias (true Kg/Eg) changes by
`mean_k dC/dtheta_j w_ie`, additive too (kept per Earth-rate component N and U, so that
"zero" holds at every latitude).

The search is a meet-in-the-middle: the groups are split into halves A and B; the
subsets of each half are classed by their normal matrix; for each pair of classes N is
fixed, so every criterion is an integer LINEAR condition on S_A + S_B, and the pairs
that satisfy it are found by joining the two halves on that key. Every one of the
C(n, m) choices is decided exactly; none is sampled.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from itertools import combinations
from pathlib import Path

import numpy as np

from bench.model.closed_form import turn_closed_form
from bench.model.earth import EARTH_RATE, Site
from bench.model.kinematics import FRAMES, attitude, frame_axes_in_body, pointing_labels, triple
from bench.model.units import DEG
from bench.schedule_design.sensitivity import probe_boxes
from schedules import RotationStep

#: The 32 inner-symmetric groups: (outer, middle, inner) with the inner angle and +180 deg.
POSITION_GROUPS = tuple((o, m, i) for o in (0, 90, 180, 270) for m in (0, 90, 180, 270) for i in (0, 90))
GROUP_SIZE = 12
_H = 1e-6  # central-difference step (rad) of the attitude derivatives; rounded to integers after


def group_angles(group) -> np.ndarray:
    """The two positions (2, 3) deg of an inner-symmetric group (outer, middle, inner0)."""
    o, m, i = group
    return np.array([[o, m, i], [o, m, (i + 180) % 360]], dtype=float)


def _integer(x: np.ndarray, what: str) -> np.ndarray:
    r = np.rint(x)
    if np.max(np.abs(x - r), initial=0.0) > 1e-6:
        raise AssertionError(f"{what} is not integral (max deviation {np.max(np.abs(x - r)):.2e})")
    return r.astype(np.int64)


def attitude_derivatives(angles_deg) -> np.ndarray:
    """dC_t^b/dtheta_j at a zero black box, (K, 9, 3, 3): integers at positive positions."""
    angles = np.asarray(angles_deg, dtype=float) * DEG
    c = attitude(angles[None, :, :], probe_boxes(_H)[:, None, :, :])     # (18, K, 3, 3)
    return ((c[:9] - c[9:]) / (2 * _H)).transpose(1, 0, 2, 3)


@dataclass(frozen=True)
class PositionTables:
    """Per-group integer contributions: normal matrix, first-order right-hand side, gyro sums."""

    groups: tuple
    normal: np.ndarray   # (G, 4, 4)
    rhs: np.ndarray      # (G, 3, 4, 9): S[c, r, j]
    gyro: np.ndarray     # (G, 3, 9, 2): sum over the group of (dC/dtheta_j e_N, e_U)[c]
    positions_per_group: int = 2


def position_tables(groups=POSITION_GROUPS) -> PositionTables:
    """Integer tables for a list of groups (each (outer, middle, inner0))."""
    angles = np.concatenate([group_angles(g) for g in groups])
    c_tb = _integer(attitude(angles * DEG), "C_t^b")
    d = _integer(attitude_derivatives(angles), "dC_t^b/dtheta")       # (K, 9, 3, 3)
    a = np.concatenate([c_tb[:, :, 2], np.ones((len(angles), 1), dtype=np.int64)], axis=1)  # f/g = C e_U
    dy = d[:, :, :, 2].transpose(0, 2, 1)                                 # (K, 3, 9)
    dw = d[:, :, :, 1:3].transpose(0, 2, 1, 3)                            # (K, 3, 9, 2): N and U columns
    g = len(groups)
    normal = np.einsum("kr,ks->krs", a, a).reshape(g, 2, 4, 4).sum(axis=1)
    rhs = np.einsum("kr,kcj->kcrj", a, dy).reshape(g, 2, 3, 4, 9).sum(axis=1)
    gyro = dw.reshape(g, 2, 3, 9, 2).sum(axis=1)
    return PositionTables(tuple(groups), normal, rhs, gyro)


def first_order_from_sums(normal: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """dP = N^-1 S for (M, 4, 4) and (M, 3, 4, 9) -> (M, 3, 4, 9); NaN where N is singular."""
    m = normal.shape[0]
    out = np.full(rhs.shape, np.nan)
    det = np.linalg.det(normal.astype(float))
    ok = np.abs(det) > 1e-9
    if ok.any():
        b = rhs[ok].astype(float).transpose(0, 2, 1, 3).reshape(int(ok.sum()), 4, 27)
        x = np.linalg.solve(normal[ok].astype(float), b)
        out[ok] = x.reshape(-1, 4, 3, 9).transpose(0, 2, 1, 3)
    return out if m else out


def position_combo_sensitivity(tables: PositionTables, combos: np.ndarray, site: Site | None = None
                               ) -> dict[str, np.ndarray]:
    """Ideal-IMU first-order sensitivities (per rad) of group combinations (M, m) of indices.

    Returns "params" (M, 3, 4, 9) = dP (NaN if rank deficient) and "gyro_bias" (M, 3, 9) in rad/s
    per rad at the site's latitude.
    """
    site = site or Site()
    combos = np.asarray(combos)
    normal = tables.normal[combos].sum(axis=1)
    rhs = tables.rhs[combos].sum(axis=1)
    w = tables.gyro[combos].sum(axis=1) / (combos.shape[1] * tables.positions_per_group)
    lat = site.latitude_deg * DEG
    gyro = EARTH_RATE * (math.cos(lat) * w[..., 0] + math.sin(lat) * w[..., 1])
    return {"params": first_order_from_sums(normal, rhs), "gyro_bias": gyro}


# --- criteria ------------------------------------------------------------------

#: Rows of dP that are scale factors and biases: (component c, parameter row r).
SCALE_BIAS_ENTRIES = tuple((c, c) for c in range(3)) + tuple((c, 3) for c in range(3))
CRITERIA_TEXT = {
    "positions": (
        "(a) full rank: the positions determine all 4 parameters of every accelerometer",
        "(b) zero first-order sensitivity of acc scale factors Ka, acc biases K0 and gyro bias D0 "
        "(true Kg/Eg) to all nine black-box angles, at every latitude",
        "(c) (b) and every first-order sensitivity, axis terms Ea included, equal to all-64's "
        "(only the inner zero offset inner.gamma remains, in Ea_Xy/Ea_Yx: no larger than all-64's)",
        "(d) optimal: (c) and the least worst-case noise variance max diag(N^-1) of the fit "
        "(equal dwell per position)",
    ),
    "rotations": (
        "(a) full rank: the 6 turns determine all 4 parameters (M_s, bias) of every gyro",
        "(b) zero first-order geometric sensitivity (Earth rate off) of the gyro scale factors Kg "
        "to all nine black-box angles",
        "(c) (b) and every first-order geometric sensitivity, axis terms Eg included, equal to all-96's "
        "(only inner.gamma remains, in Eg_Xy/Eg_Yx)",
        "(d) optimal: (c) and the least noise variance (every one-pair-per-axis set has the same "
        "normal matrix, so (d) = (c)); ranked by Earth-rate coupling, reported separately",
    ),
}


def _adjugate(n: np.ndarray) -> tuple[np.ndarray, int]:
    """Integer adjugate and determinant of an integer 4x4 matrix (exact via round of float)."""
    det = int(round(np.linalg.det(n.astype(float))))
    if det == 0:
        return np.zeros_like(n), 0
    adj = np.rint(np.linalg.inv(n.astype(float)) * det).astype(np.int64)
    if not np.array_equal(adj @ n, det * np.eye(4, dtype=np.int64)):
        raise AssertionError("adjugate not exact")
    return adj, det


def _subsets(n_items: int, k: int) -> np.ndarray:
    if k == 0:
        return np.zeros((1, 0), dtype=np.int64)
    if k > n_items:
        return np.zeros((0, k), dtype=np.int64)
    return np.array(list(combinations(range(n_items), k)), dtype=np.int64)


def _rows_key(x: np.ndarray) -> np.ndarray:
    x = np.ascontiguousarray(x.reshape(len(x), -1).astype(np.int64))
    return x.view(np.dtype((np.void, x.dtype.itemsize * x.shape[1]))).ravel()


def join_zero_sum(ka: np.ndarray, kb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All (i, j) with ka[i] + kb[j] == 0 (integer rows), by sorting keys."""
    if len(ka) == 0 or len(kb) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    va, vb = _rows_key(-ka), _rows_key(kb)
    order = np.argsort(vb, kind="stable")
    vb_sorted = vb[order]
    lo = np.searchsorted(vb_sorted, va, side="left")
    hi = np.searchsorted(vb_sorted, va, side="right")
    counts = hi - lo
    ia = np.repeat(np.arange(len(ka)), counts)
    offsets = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    ib = order[np.repeat(lo, counts) + offsets]
    return ia, ib


def count_zero_sum(ka: np.ndarray, kb: np.ndarray) -> int:
    """How many (i, j) have ka[i] + kb[j] == 0, without listing them."""
    if len(ka) == 0 or len(kb) == 0:
        return 0
    keys, inverse = np.unique(np.concatenate([_rows_key(-ka), _rows_key(kb)]), return_inverse=True)
    inverse = inverse.ravel()
    ca = np.bincount(inverse[:len(ka)], minlength=len(keys))
    cb = np.bincount(inverse[len(ka):], minlength=len(keys))
    return int(np.sum(ca * cb))


@dataclass
class SearchResult:
    """Counts per criterion and the combinations meeting (c)/(d), as index arrays into `groups`."""

    kind: str
    items: tuple                  # groups (positions) or candidate rotations
    choose: int
    total: int
    counts: dict[str, int]
    equivalent: np.ndarray        # (E, m) combos meeting (c)
    optimal: np.ndarray           # (O, m) combos meeting (d)
    elapsed_s: float = 0.0
    extra: dict = field(default_factory=dict)


def _position_key(tables: PositionTables, idx: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3, 4, 9) integer S and (n, 3, 9, 2) gyro sums of subsets `idx` (n, k) of the half `rows`."""
    if idx.shape[1] == 0:
        return np.zeros((len(idx), 3, 4, 9), dtype=np.int64), np.zeros((len(idx), 3, 9, 2), dtype=np.int64)
    sel = rows[idx]
    return tables.rhs[sel].sum(axis=1), tables.gyro[sel].sum(axis=1)


def _zero_sum_key(lin: np.ndarray, comp: np.ndarray, s: np.ndarray, w: np.ndarray, members: np.ndarray) -> np.ndarray:
    """Per member subset: the (b) quantities (scale and bias rows of adj(N) S, gyro sums) that must sum to zero."""
    proj = np.einsum("er,nerj->nej", lin, s[members][:, comp])   # (n, 6, 9)
    return np.concatenate([proj.reshape(len(members), -1), w[members].reshape(len(members), -1)], axis=1)


def search_positions(groups=POSITION_GROUPS, choose: int = GROUP_SIZE, reference_groups=None,
                     progress: Callable[[int, int], None] | None = None) -> SearchResult:
    """Exhaustive search over all `choose`-subsets of `groups` (see module docstring).

    `reference_groups` (default: all of `groups`) is the "use them all" schedule whose
    first-order sensitivities (c) compares against; all 32 groups = all 64 positions.
    `progress(searched, total)` is called as the subsets are searched (the last call has searched == total).
    """
    started = time.perf_counter()
    tables = position_tables(groups)
    n = len(groups)
    ref = position_tables(reference_groups) if reference_groups is not None else tables
    ref_dp = first_order_from_sums(ref.normal.sum(axis=0)[None], ref.rhs.sum(axis=0)[None])[0]
    half = n // 2
    rows_a, rows_b = np.arange(half), np.arange(half, n)
    counts = {"total": math.comb(n, choose), "a": 0, "b": 0, "c": 0, "d": 0}
    equivalent, var_cost = [], []
    searched = 0
    for k in range(max(0, choose - (n - half)), min(choose, half) + 1):
        sub_a, sub_b = _subsets(half, k), _subsets(n - half, choose - k)
        if len(sub_a) == 0 or len(sub_b) == 0:
            continue
        na = tables.normal[rows_a[sub_a]].sum(axis=1) if k else np.zeros((1, 4, 4), dtype=np.int64)
        nb = tables.normal[rows_b[sub_b]].sum(axis=1) if choose - k else np.zeros((1, 4, 4), dtype=np.int64)
        sa, wa = _position_key(tables, sub_a, rows_a)
        sb, wb = _position_key(tables, sub_b, rows_b)
        cls_a, inv_a = np.unique(na.reshape(len(na), 16), axis=0, return_inverse=True)
        cls_b, inv_b = np.unique(nb.reshape(len(nb), 16), axis=0, return_inverse=True)
        inv_a, inv_b = inv_a.ravel(), inv_b.ravel()
        members_a = [np.flatnonzero(inv_a == i) for i in range(len(cls_a))]
        members_b = [np.flatnonzero(inv_b == i) for i in range(len(cls_b))]
        for ia_cls, ma in enumerate(members_a):
            for ib_cls, mb in enumerate(members_b):
                searched += len(ma) * len(mb)
                if progress is not None:
                    progress(searched, counts["total"])
                normal = (cls_a[ia_cls] + cls_b[ib_cls]).reshape(4, 4)
                adj, det = _adjugate(normal)
                if det == 0:
                    continue
                counts["a"] += len(ma) * len(mb)
                # (b): the scale and bias rows of adj(N) S vanish, and the gyro sums vanish.
                lin = np.stack([adj[r] for _, r in SCALE_BIAS_ENTRIES])            # (6, 4)
                comp = np.array([c for c, _ in SCALE_BIAS_ENTRIES])
                pa, pb = join_zero_sum(_zero_sum_key(lin, comp, sa, wa, ma), _zero_sum_key(lin, comp, sb, wb, mb))
                if len(pa) == 0:
                    continue
                counts["b"] += len(pa)
                # (c): adj(N) S == det * dP_ref exactly, on the (b) survivors.
                s_tot = sa[ma[pa]] + sb[mb[pb]]
                full = np.einsum("rs,ncsj->ncrj", adj, s_tot)
                target = np.rint(det * ref_dp).astype(np.int64)
                if not np.allclose(det * ref_dp, target, atol=1e-6):
                    raise AssertionError("reference sensitivity is not a multiple of 1/det")
                ok = np.all((full == target[None]).reshape(len(pa), -1), axis=1)
                if not ok.any():
                    continue
                counts["c"] += int(ok.sum())
                combos = np.concatenate([rows_a[sub_a[ma[pa[ok]]]], rows_b[sub_b[mb[pb[ok]]]]], axis=1)
                equivalent.append(combos)
                var_cost.append(np.full(len(combos), float(np.max(np.diag(np.linalg.inv(normal.astype(float)))))))
    if progress is not None:
        progress(counts["total"], counts["total"])
    eq = np.concatenate(equivalent) if equivalent else np.zeros((0, choose), dtype=np.int64)
    cost = np.concatenate(var_cost) if var_cost else np.zeros(0)
    opt = eq[np.isclose(cost, cost.min())] if len(eq) else eq
    counts["d"] = len(opt)
    order = np.lexsort(opt.T[::-1]) if len(opt) else np.zeros(0, dtype=np.int64)
    return SearchResult("positions", tuple(groups), choose, counts["total"], counts, eq, opt[order],
                        time.perf_counter() - started, {"min_variance": float(cost.min()) if len(cost) else math.nan})


def combo_of_angles(angles_deg, groups=POSITION_GROUPS) -> tuple[int, ...] | None:
    """Group indices of a position schedule made of whole inner-symmetric groups, else None."""
    keys = {tuple(int(v) % 360 for v in a) for a in np.asarray(angles_deg, dtype=float)}
    chosen = []
    for idx, g in enumerate(groups):
        pair = {tuple(int(v) for v in a) for a in group_angles(g)}
        if pair <= keys:
            chosen.append(idx)
            keys -= pair
    return tuple(chosen) if not keys else None


# --- rotations -----------------------------------------------------------------

def all_rotations(revolutions: int = 1) -> tuple:
    """The 96 rotations: 48 positive initial states (turning frame at 0) x CCW/CW."""
    out = []
    for frame_index, frame in enumerate(FRAMES):
        others = [k for k in range(3) if k != frame_index]
        for a in (0, 90, 180, 270):
            for b in (0, 90, 180, 270):
                start = [0.0, 0.0, 0.0]
                start[others[0]], start[others[1]] = float(a), float(b)
                for direction in ("ccw", "cw"):
                    out.append(RotationStep(triple(start), frame, direction, revolutions))
    return tuple(out)


def rotation_axes(turns) -> np.ndarray:
    """Signed body rotation axis (K, 3) integers: direction sign x turning frame axis at the start."""
    axes = np.array([frame_axes_in_body(np.asarray(t.start_deg) * DEG)[t.frame_index] * t.sign for t in turns])
    return _integer(axes, "turn axis")


def rotation_geometry(turns) -> tuple[np.ndarray, np.ndarray]:
    """Earth-free design rows [v, 1] (K, 4) (units 2 pi N and T) and d(axis)/dtheta (K, 3, 9) integers."""
    v = rotation_axes(turns)
    d = []
    for t in turns:
        ax = frame_axes_in_body(np.asarray(t.start_deg)[None] * DEG, probe_boxes(_H))[:, t.frame_index]  # (18, 3)
        d.append(t.sign * (ax[:9] - ax[9:]).T / (2 * _H))
    return (np.concatenate([v, np.ones((len(v), 1), dtype=np.int64)], axis=1),
            _integer(np.array(d), "d(turn axis)/dtheta"))


def rotation_tables(turns, site: Site | None = None, rate_dps: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    """Per-turn design rows (K, 4) SI and d(integral)/dtheta (K, 3, 9), Earth rate included, ideal IMU."""
    site = site or Site()
    rot, earth, dur = turn_closed_form(turns, site, rate_dps)
    rp, ep, _ = turn_closed_form(turns, site, rate_dps, probe_boxes(_H))              # (18, K, 3)
    y = rp + ep
    return np.column_stack([rot + earth, dur]), ((y[:9] - y[9:]) / (2 * _H)).transpose(1, 2, 0)


def rotation_set_sensitivity(tables: tuple[np.ndarray, np.ndarray], sets: np.ndarray) -> np.ndarray:
    """Ideal-IMU first-order dP (M, 3, 4, 9) per rad of index sets (M, k) into `rotation_tables`."""
    a, dy = tables[0][sets], tables[1][sets]
    return first_order_from_sums(np.einsum("mkr,mks->mrs", a, a), np.einsum("mkr,mkcj->mcrj", a, dy))


def search_rotations(turns=None, site: Site | None = None, rate_dps: float = 10.0) -> SearchResult:
    """All sets of one (+u, -u) pair of turns per body axis u, from `turns` (default the 96)."""
    started = time.perf_counter()
    turns = tuple(turns) if turns is not None else all_rotations()
    a, d = rotation_geometry(turns)
    v = a[:, :3]
    pairs = []
    for u in range(3):
        plus = np.flatnonzero(v[:, u] == 1)
        minus = np.flatnonzero(v[:, u] == -1)
        pairs.append(np.array([(p, q) for p in plus for q in minus], dtype=np.int64).reshape(-1, 2))
    total = math.prod(len(p) for p in pairs)
    normal_k = np.einsum("kr,ks->krs", a, a)
    rhs_k = np.einsum("kr,kcj->kcrj", a, d)
    ref_dp = first_order_from_sums(normal_k.sum(axis=0)[None], rhs_k.sum(axis=0)[None])[0]
    counts = {"total": total, "a": 0, "b": 0, "c": 0, "d": 0}
    if total == 0:
        empty = np.zeros((0, 6), dtype=np.int64)
        return SearchResult("rotations", turns, 6, 0, counts, empty, empty, time.perf_counter() - started)
    xy = np.array([np.concatenate([px, py]) for px in pairs[0] for py in pairs[1]])
    z = pairs[2]
    n_xy = normal_k[xy].sum(axis=1)
    n_z = normal_k[z].sum(axis=1)
    if len(np.unique(n_xy.reshape(-1, 16), axis=0)) != 1 or len(np.unique(n_z.reshape(-1, 16), axis=0)) != 1:
        raise AssertionError("one-pair-per-axis sets should share one normal matrix")
    adj, det = _adjugate(n_xy[0] + n_z[0])
    counts["a"] = total if det else 0
    s_xy, s_z = rhs_k[xy].sum(axis=1), rhs_k[z].sum(axis=1)
    lin = np.stack([adj[c] for c in range(3)])                                      # scale rows (c, c)

    def key(s):
        return np.einsum("cr,ncrj->ncj", lin, s).reshape(len(s), -1)
    counts["b"] = count_zero_sum(key(s_xy), key(s_z))
    # (c): the M rows (scale and axes; the bias row is not a rotation-method result) of
    # adj(N) S equal det * dP_ref: linear in S, so one join decides every set.
    target = np.rint(det * ref_dp[:, :3]).astype(np.int64)
    if not np.allclose(det * ref_dp[:, :3], target, atol=1e-6):
        raise AssertionError("reference sensitivity is not a multiple of 1/det")
    full_xy = np.einsum("rs,ncsj->ncrj", adj[:3], s_xy) - target[None]
    full_z = np.einsum("rs,ncsj->ncrj", adj[:3], s_z)
    ia, ib = join_zero_sum(full_xy.reshape(len(xy), -1), full_z.reshape(len(z), -1))
    eq = np.concatenate([xy[ia], z[ib]], axis=1)
    counts["c"] = counts["d"] = len(eq)
    coupling = np.zeros(len(eq))
    if len(eq):
        tables = rotation_tables(turns, site, rate_dps)
        ref_earth = rotation_set_sensitivity(tables, np.arange(len(turns))[None])[0]
        for lo in range(0, len(eq), 4096):
            chunk = eq[lo:lo + 4096]
            dp = rotation_set_sensitivity(tables, chunk)
            coupling[lo:lo + 4096] = np.max(np.abs(dp[:, :, :3] - ref_earth[None, :, :3]).reshape(len(chunk), -1),
                                            axis=1)
    order = np.lexsort((*eq.T[::-1], np.round(coupling, 12)))
    eq, coupling = eq[order], coupling[order]
    counts["earth_free"] = int(np.sum(coupling < 1e-7))
    return SearchResult("rotations", turns, 6, total, counts, eq, eq, time.perf_counter() - started,
                        {"earth_coupling": coupling})


def combo_of_turns(turns, candidates=None) -> tuple[int, ...] | None:
    """Indices into `candidates` (default the 96) of a rotation schedule's turns, else None."""
    candidates = candidates if candidates is not None else all_rotations()
    index = {(tuple(float(x) for x in c.start_deg), c.frame, c.direction): i for i, c in enumerate(candidates)}
    out = []
    for t in turns:
        i = index.get((tuple(float(x) for x in t.start_deg), t.frame, t.direction))
        if i is None:
            return None
        out.append(i)
    return tuple(sorted(out))


# --- schedule files ------------------------------------------------------------

def _pointing(angles_deg) -> str:
    return pointing_labels(attitude(np.radians(np.asarray(angles_deg, dtype=float))))


def position_schedule_toml(name: str, description: str, groups) -> str:
    """A shipped-format positions schedule of whole inner-symmetric groups."""
    lines = ["# Written by `bench schedules search`: inner-symmetric groups (inner angles 180 deg apart).",
             "", 'format = "turntable-bench/schedule"', "version = 1", f'name = "{name}"', 'kind = "positions"',
             f'description = "{description}"', ""]
    for number, g in enumerate(groups, start=1):
        for a in group_angles(g):
            lines += ["[[position]]", f"angles_deg = [{int(a[0])}, {int(a[1])}, {int(a[2])}]  "
                      f"# body X Y Z -> {_pointing(a)}", f"group = {number}", ""]
    return "\n".join(lines)


def rotation_schedule_toml(name: str, description: str, turns) -> str:
    """A shipped-format rotations schedule."""
    lines = ["# Written by `bench schedules search`: one +u/-u pair of turns per body axis u.",
             "", 'format = "turntable-bench/schedule"', "version = 1", f'name = "{name}"', 'kind = "rotations"',
             f'description = "{description}"', ""]
    for t in turns:
        s = t.start_deg
        lines += ["[[rotation]]", f"start_deg = [{int(s[0])}, {int(s[1])}, {int(s[2])}]  "
                  f"# body X Y Z -> {_pointing(s)}", f'frame = "{t.frame}"', f'direction = "{t.direction}"',
                  f"revolutions = {t.revolutions}", ""]
    return "\n".join(lines)


def write_best(result: SearchResult, out_dir, best: int, prefix: str = "search") -> list:
    """Write the first `best` optimal sets as schedule files in `out_dir`; returns the paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for rank, combo in enumerate(result.optimal[:best], start=1):
        if result.kind == "positions":
            name = f"{prefix}-24-{rank}"
            text = position_schedule_toml(name, f"Search result {rank}: first-order equivalent to all-64, "
                                          "least noise", [result.items[i] for i in combo])
        else:
            name = f"{prefix}-6r-{rank}"
            coupling = result.extra.get("earth_coupling")
            note = f", Earth coupling {coupling[rank - 1]:.2e}" if coupling is not None else ""
            text = rotation_schedule_toml(name, f"Search result {rank}: first-order equivalent to all-96{note}",
                                          [result.items[i] for i in combo])
        path = out / f"{name}.toml"
        path.write_text(text, encoding="utf-8")
        paths.append(path)
    return paths
