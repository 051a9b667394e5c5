"""The union of the coverage polygons on a raster, in compiled loops (numba): the overlap excess that
``geometry.CoverageGeometry.union_area`` subtracts from the sum of the per-agent areas, and each agent's marginal
share of the union (the difference credit). Exact against shapely within the raster's error
(``tests/world/test_geometry.py``)."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def near_another(xy, reach2):  # pragma: no cover
    """Whether each agent is closer than √reach2 to another of its environment: xy [E, N, 2] → [E, N] bool.
    (In numpy the pairwise test over [E, N, N, 2] cost more than the raster kernel below.)"""
    n_env, n = xy.shape[0], xy.shape[1]
    out = np.zeros((n_env, n), np.bool_)
    for e in range(n_env):
        for i in range(n):
            for j in range(i + 1, n):
                dx = xy[e, i, 0] - xy[e, j, 0]
                dy = xy[e, i, 1] - xy[e, j, 1]
                if dx * dx + dy * dy < reach2:
                    out[e, i] = True
                    out[e, j] = True
    return out


@njit(cache=True)
def overlap_runs(env, cell, k, box, lo, hi, reach, prefix, marginal):  # pragma: no cover
    """Raster kernel of ``union_area``: per stamp, (its environment's excess of the stamps' cells over their
    union, on the environment's first stamp; its cells covered twice or more, counted only when ``marginal``),
    cells inside the region only.

    Long on purpose: one compiled sweep, whose state (the active stamps in row order) would cost a copy per
    call if split into functions numba cannot inline.

    A stamp is agent ``cell`` [M, 2]'s stencil ``k`` [M]: rows ``lo[k, c] .. hi[k, c]`` of column c, inside its
    bounding box ``box`` [M, 4] (x0, x1, y0, y1, inclusive, in cells); stamps of one environment are consecutive
    (``env`` [M]). K is convex and a raster cell at most R/2 wide, so a stamp meets every column of its box in
    exactly one run of rows (``_build_raster`` checks it), and the kernel works on runs, not cells. It sweeps an
    environment's columns left to right with the stamps that meet the column (they enter and leave at their
    boxes' sides), kept in order of their runs' first rows: from one column to the next that order barely
    changes, so re-sorting it is about linear. ``prefix`` [nx, ny + 1] counts a piece's cells in the region
    (row r: the column's region cells below row r).

    Excess of a column = the runs' region cells − their union's region cells (the union merged from the runs in
    order). When ``marginal``, a sweep over the runs' ends in row order (``_runs_alone``) keeps instead how many
    stamps cover the current piece and the sum of their numbers (the stamp itself while only one does): a
    stamp's cells covered twice or more are its cells less those it covers alone. Returns out [M, 2]."""
    m = len(cell)
    out = np.zeros((m, 2))
    alone = np.zeros(m)  # cells a stamp covers by itself, in the columns it shares
    first = np.empty(m, np.int64)  # the current column's run of each stamp: rows first .. end - 1
    end = np.empty(m, np.int64)
    left = np.ascontiguousarray(box[:, 0])
    by_left = np.arange(m)  # an environment's stamps in the order they enter the sweep
    by_first = np.empty(m, np.int64)  # the stamps meeting the column, in order of first row
    at = np.empty(2 * m, np.int64)  # the marginal sweep's events: row, +1/−1, stamp
    step = np.empty(2 * m, np.int64)
    owner = np.empty(2 * m, np.int64)
    start = 0
    while start < m:
        stop = start
        while stop < m and env[stop] == env[start]:
            stop += 1
        entering, meeting = by_left[start:stop], by_first[start:stop]
        _sort_by(entering, left, stop - start)
        x_last = box[start, 1]
        for i in range(start + 1, stop):
            x_last = max(x_last, box[i, 1])
        entered, count, excess = 0, 0, 0.0
        for x in range(left[entering[0]], x_last + 1):
            count = _keep_reaching(meeting, count, box, x)
            while entered < stop - start and left[entering[entered]] <= x:
                meeting[count] = entering[entered]
                count += 1
                entered += 1
            if count < 2:  # fewer than two stamps: nothing shared in this column
                continue
            for j in range(count):
                i = meeting[j]
                col = x - cell[i, 0] + reach
                first[i] = cell[i, 1] + lo[k[i], col]
                end[i] = cell[i, 1] + hi[k[i], col] + 1
            _sort_by(meeting, first, count)
            if marginal:
                excess += _runs_alone(x, meeting, count, first, end, prefix, at, step, owner, out, alone)
                continue
            cells, union = 0, 0
            bottom, top = first[meeting[0]], end[meeting[0]]  # the merged run being built
            for j in range(count):
                i = meeting[j]
                cells += prefix[x, end[i]] - prefix[x, first[i]]
                if first[i] > top:
                    union += prefix[x, top] - prefix[x, bottom]
                    bottom, top = first[i], end[i]
                elif end[i] > top:
                    top = end[i]
            union += prefix[x, top] - prefix[x, bottom]  # the last merged run
            excess += cells - union
        out[start, 0] = excess
        start = stop
    if marginal:
        out[:, 1] -= alone
    return out


@njit(cache=True)
def _runs_alone(x, meeting, count, first, end, prefix, at, step, owner, out, alone):  # pragma: no cover
    """One column of ``overlap_runs``'s marginal sweep over the runs of ``meeting`` [count]: their ends, in row
    order in ``at``, ``step`` (+1 a start, −1 an end) and ``owner`` (the stamp), mark the pieces between them; each
    run adds its region cells to ``out[:, 1]`` and the cells it covers alone to ``alone``. Runs are half-open
    [first, end): the pieces between consecutive events, empty ones skipped, are what the counts hold for.
    → the column's excess (a piece covered c ≥ 1 times: c − 1 a cell)."""
    events = 0
    for j in range(count):
        i = meeting[j]
        events = _insert(at, step, owner, events, first[i], 1, i)
        events = _insert(at, step, owner, events, end[i], -1, i)
    covering, ids, row, excess = 0, 0, at[0], 0
    for e in range(events):
        if at[e] > row and covering > 0:
            cells = prefix[x, at[e]] - prefix[x, row]
            excess += (covering - 1) * cells
            if covering == 1:
                alone[ids] += cells
        row = at[e]
        covering += step[e]
        ids += step[e] * owner[e]
        if step[e] > 0:
            out[owner[e], 1] += prefix[x, end[owner[e]]] - prefix[x, row]
    return excess


@njit(cache=True)
def _insert(at, step, owner, count, row, delta, stamp):  # pragma: no cover
    """Insert the event (row, delta, stamp) into the first ``count`` events, kept in row order. → count + 1."""
    j = count
    while j > 0 and at[j - 1] > row:
        at[j], step[j], owner[j] = at[j - 1], step[j - 1], owner[j - 1]
        j -= 1
    at[j], step[j], owner[j] = row, delta, stamp
    return count + 1


@njit(cache=True)
def _sort_by(order, key, n):  # pragma: no cover
    """Insertion sort of ``order[:n]`` by ``key[order]``, in place: about linear on an order that is nearly right."""
    for j in range(1, n):
        v = order[j]
        i = j
        while i > 0 and key[order[i - 1]] > key[v]:
            order[i] = order[i - 1]
            i -= 1
        order[i] = v


@njit(cache=True)
def _keep_reaching(order, n, box, x):  # pragma: no cover
    """Drop from ``order[:n]`` the stamps whose box ends before column ``x``, keeping the rest's order. → count."""
    kept = 0
    for j in range(n):
        i = order[j]
        if box[i, 1] >= x:
            order[kept] = i
            kept += 1
    return kept
