"""Visiting order of plan units: an open path from a fixed start with a free end, least total cost.

Exact (Held-Karp DP) for small sets; above that, nearest neighbour from several first
units improved by 2-opt and Or-opt (best improvement, vectorised with numpy, asymmetric
costs handled) and a fixed number of seeded double-bridge kicks: deterministic.
"""

from __future__ import annotations

import numpy as np

# Above this many units the visiting order comes from the heuristic, below it is exact (DP).
EXACT_MAX_UNITS = 9


def _path_cost(start: np.ndarray, cost: np.ndarray, order) -> float:
    if len(order) == 0:
        return 0.0
    return float(start[order[0]] + sum(cost[a, b] for a, b in zip(order[:-1], order[1:])))


def _exact_order(start: np.ndarray, cost: np.ndarray) -> list[int]:
    """Held-Karp DP over subsets (n <= ~12)."""
    n = len(start)
    full = (1 << n) - 1
    best = {(1 << j, j): (float(start[j]), -1) for j in range(n)}
    for mask in range(1, full + 1):
        for j in range(n):
            entry = best.get((mask, j))
            if entry is None:
                continue
            for nxt in range(n):
                if mask & (1 << nxt):
                    continue
                key, value = (mask | (1 << nxt), nxt), entry[0] + cost[j, nxt]
                if key not in best or value < best[key][0] - 1e-12:
                    best[key] = (value, j)
    j = min(range(n), key=lambda t: (best[(full, t)][0], t))
    order, mask = [], full
    while j >= 0:
        order.append(j)
        j, mask = best[(mask, j)][1], mask & ~(1 << j)
    return order[::-1]


def _nearest_neighbour(start: np.ndarray, cost: np.ndarray, first: int) -> list[int]:
    n = len(start)
    order, free = [first], np.ones(n, dtype=bool)
    free[first] = False
    for _ in range(n - 1):
        row = np.where(free, cost[order[-1]], np.inf)
        nxt = int(np.argmin(row))
        order.append(nxt)
        free[nxt] = False
    return order


def _local_search(m: np.ndarray, path: np.ndarray, max_rounds: int = 2000) -> np.ndarray:
    """Best-improvement 2-opt and Or-opt (segments of 1..3, either way round) on a path with fixed ends.

    `m` is the (n+2)^2 matrix with node 0 = start and node n+1 = a free end (cost 0 into it).
    Asymmetric costs are handled (a reversed segment is re-costed).
    """
    n = len(path) - 2
    idx = np.arange(1, n + 1)
    for _ in range(max_rounds):
        fwd = np.concatenate([[0.0], np.cumsum(m[path[:-1], path[1:]])])   # fwd[k]: cost of edges before k
        back = m[path[1:], path[:-1]]
        back[0] = back[-1] = 0.0     # the edges at the fixed ends never lie inside a reversed segment
        bwd = np.concatenate([[0.0], np.cumsum(back)])
        best_delta, best_move = -1e-9, None
        # 2-opt: reverse path[i..j], 1 <= i < j <= n.
        i, j = idx[:, None], idx[None, :]
        delta = (m[path[i - 1], path[j]] + m[path[i], path[j + 1]] - m[path[i - 1], path[i]]
                 - m[path[j], path[j + 1]] + (bwd[j] - bwd[i]) - (fwd[j] - fwd[i]))
        delta = np.where(j > i, delta, np.inf)
        flat = int(np.argmin(delta))
        if delta.flat[flat] < best_delta:
            best_delta, best_move = float(delta.flat[flat]), ("2opt", flat // n + 1, flat % n + 1, 0, False)
        # Or-opt: move path[i..i+L-1] between path[k] and path[k+1].
        k = np.arange(0, n + 1)[None, :]
        for length in (1, 2, 3):
            if length >= n:
                break
            i = np.arange(1, n - length + 2)[:, None]
            a, s0, s1, b = path[i - 1], path[i], path[i + length - 1], path[i + length]
            c, d = path[k], path[k + 1]
            removed = m[a, s0] + m[s1, b] + m[c, d] - m[a, b]
            inner = (bwd[i + length - 1] - bwd[i]) - (fwd[i + length - 1] - fwd[i])
            ok = (k < i - 1) | (k > i + length - 1)
            for reverse in (False, True):
                added = (m[c, s1] + m[s0, d] + inner) if reverse else (m[c, s0] + m[s1, d])
                delta = np.where(ok, added - removed, np.inf)
                flat = int(np.argmin(delta))
                if delta.flat[flat] < best_delta:
                    cols = n + 1
                    best_delta = float(delta.flat[flat])
                    best_move = ("or", flat // cols + 1, flat % cols, length, reverse)
        if best_move is None:
            return path
        kind, bi, bj, length, reverse = best_move   # the best move's i and j (ints; i, j above are arrays)
        p = list(path)
        if kind == "2opt":
            p[bi:bj + 1] = p[bi:bj + 1][::-1]
        else:
            seg = p[bi:bi + length]
            seg = seg[::-1] if reverse else seg
            rest = p[:bi] + p[bi + length:]
            at = bj + 1 if bj < bi else bj + 1 - length   # insert after old position j
            p = rest[:at] + seg + rest[at:]
        path = np.array(p)
    return path


def _double_bridge(order: list[int], rng: np.random.Generator) -> list[int]:
    n = len(order)
    a, b, c = sorted(rng.choice(np.arange(1, n), size=3, replace=False))
    return order[:a] + order[b:c] + order[a:b] + order[c:]


def order_units(start: np.ndarray, cost: np.ndarray, exact_max: int = EXACT_MAX_UNITS,
                starts: int = 6, kicks: int = 30, seed: int = 0) -> list[list[int]]:
    """Candidate visiting orders (best first) minimising start[o0] + sum cost[o_k, o_k+1].

    Exact (DP) up to `exact_max` units; above, nearest-neighbour from the `starts` cheapest
    first units, each improved by 2-opt + Or-opt, then `kicks` double-bridge perturbations
    of the best (deterministic for a given `seed`).
    """
    n = len(start)
    if n <= 1:
        return [list(range(n))]
    if n <= exact_max:
        return [_exact_order(start, cost)]
    m = np.zeros((n + 2, n + 2))
    m[0, 1:n + 1] = start
    m[1:n + 1, 1:n + 1] = cost
    m[:, 0] = 1e12                # nothing goes back to the start
    m[n + 1, :] = 1e12            # nothing leaves the end

    def improve(order):
        path = _local_search(m, np.array([0] + [o + 1 for o in order] + [n + 1]))
        return [int(x) - 1 for x in path[1:-1]]

    if n > 128:               # keep big sets (e.g. the 324-position table check) to a few seconds
        starts, kicks = min(starts, 2), min(kicks, 4)
    firsts = [int(x) for x in np.argsort(start, kind="stable")[:starts]]
    found = [improve(_nearest_neighbour(start, cost, f)) for f in firsts]
    found.sort(key=lambda o: _path_cost(start, cost, o))
    best = found[0]
    rng = np.random.default_rng(seed)
    for _ in range(kicks if n >= 8 else 0):
        trial = improve(_double_bridge(best, rng))
        if _path_cost(start, cost, trial) < _path_cost(start, cost, best) - 1e-9:
            best = trial
            found.insert(0, trial)
    unique = []
    for o in [best] + found:
        if o not in unique:
            unique.append(o)
    return unique
