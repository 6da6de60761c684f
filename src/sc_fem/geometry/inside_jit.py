"""Compiled ray-crossing count of :func:`sc_fem.geometry.rays.crossing_number` (numba, optional).

The numpy path expands every (point, face over its bin) pair into arrays; this kernel visits the
same pairs point by point, with the same arithmetic in the same order (the edge signs
of :func:`sc_fem.geometry.rays._edge_signs`, the face's height from the same sub-areas), so both
count the same crossings. The faces are binned on the xy grid by a counting sort
(:data:`bin_faces`) that gives the numpy path's arrays (a stable sort of the (bin, face) pairs)
exactly. Without numba (the optional extra ``sc_fem[fast]``) the numpy path runs.
"""

from __future__ import annotations

import numpy as np

from .._jit import compiled, compiled_inline, compiled_parallel, prange


def _edge_sign_py(ax, ay, bx, by, px, py):  # pragma: no cover - compiled
    """Scalar :func:`sc_fem.geometry.rays._edge_signs`: side (+1, -1, 0) of ``p`` from ``a -> b``."""
    swap = (ax > bx) or (ax == bx and ay > by)
    if swap:
        lx, ly, hx, hy = bx, by, ax, ay
    else:
        lx, ly, hx, hy = ax, ay, bx, by
    dx, dy = hx - lx, hy - ly
    orient = dx * (py - ly) - dy * (px - lx)
    if orient == 0:
        orient = -dy if dy != 0 else dx
    sign = 1.0 if orient > 0 else (-1.0 if orient < 0 else 0.0)
    return -sign if swap else sign


_edge_sign = compiled(_edge_sign_py)


RUN = 256
"""Points each parallel task of :data:`crossings` takes in order (so that it can reuse a ray)."""

RAY_CACHE = 512
"""Faces a reused ray may cross (more: each point on it is counted alone)."""


def _face_under_py(t, px, py):  # pragma: no cover - compiled
    """Height of face ``t`` (3, 3) at ``(px, py)`` and its sign, or sign 0 when the point's projection
    is outside the face (or the face's box), with the edge signs of :func:`_edge_sign_py`."""
    if not (min(t[0, 0], t[1, 0], t[2, 0]) <= px <= max(t[0, 0], t[1, 0], t[2, 0])
            and min(t[0, 1], t[1, 1], t[2, 1]) <= py <= max(t[0, 1], t[1, 1], t[2, 1])):
        return 0.0, 0.0
    s0 = _edge_sign(t[0, 0], t[0, 1], t[1, 0], t[1, 1], px, py)
    s1 = _edge_sign(t[1, 0], t[1, 1], t[2, 0], t[2, 1], px, py)
    s2 = _edge_sign(t[2, 0], t[2, 1], t[0, 0], t[0, 1], px, py)
    if s0 == 0 or s0 != s1 or s1 != s2:
        return 0.0, 0.0
    l0 = (t[1, 0] - px) * (t[2, 1] - py) - (t[1, 1] - py) * (t[2, 0] - px)
    l1 = (t[2, 0] - px) * (t[0, 1] - py) - (t[2, 1] - py) * (t[0, 0] - px)
    l2 = (t[0, 0] - px) * (t[1, 1] - py) - (t[0, 1] - py) * (t[1, 0] - px)
    return (l0 * t[0, 2] + l1 * t[1, 2] + l2 * t[2, 2]) / (l0 + l1 + l2), s0


_face_under = compiled(_face_under_py)


def _ray_crossings_py(tri, start, bin_face, b, px, py, zs, tops, signs):  # pragma: no cover - compiled
    """The crossings of the ray through ``(px, py)`` (bin ``b``): each one's height, the top of its
    face and its sign into ``zs``, ``tops``, ``signs``; their number, or -1 past :data:`RAY_CACHE`."""
    cached = 0
    for k in range(start[b], start[b + 1]):
        t = tri[bin_face[k]]
        z, s = _face_under(t, px, py)
        if s != 0:
            if cached == RAY_CACHE:
                return -1
            zs[cached], tops[cached], signs[cached] = z, max(t[0, 2], t[1, 2], t[2, 2]), s
            cached += 1
    return cached


_ray_crossings = compiled_inline(_ray_crossings_py)


def _crossings_above_py(tri, start, bin_face, b, px, py, pz, cached, zs, tops, signs):  # pragma: no cover - compiled
    """Signed crossings above ``(px, py, pz)``: from the ray's ``cached`` crossings (those whose
    face's top and height exceed ``pz``), or, with ``cached < 0``, face by face over bin ``b`` --
    the same faces either way."""
    acc = 0.0
    if cached >= 0:
        for j in range(cached):
            if tops[j] > pz and zs[j] > pz:
                acc += signs[j]
        return acc
    for k in range(start[b], start[b + 1]):
        t = tri[bin_face[k]]
        if max(t[0, 2], t[1, 2], t[2, 2]) > pz:
            z, s = _face_under(t, px, py)
            if s != 0 and z > pz:
                acc += s
    return acc


_crossings_above = compiled_inline(_crossings_above_py)


def _crossings_py(q, tri, lo, hi, size, nb, start, bin_face, out):  # pragma: no cover - compiled
    """Signed crossings above each point ``q`` (n, 3) of the binned faces ``tri`` (m, 3, 3), into ``out`` (n,).

    Consecutive points with the same ``(x, y)`` share a ray: its crossings (height, top of the
    face, sign) are found once and each point sums those above it, which counts the same faces
    (a face above the point, ``max z > z_p``, whose height there exceeds ``z_p``) as a point alone."""
    n = q.shape[0]
    for r in prange((n + RUN - 1) // RUN):
        zs = np.empty(RAY_CACHE)
        tops = np.empty(RAY_CACHE)
        signs = np.empty(RAY_CACHE)
        cached = -1                              # crossings of the ray through (cx, cy); -1: none
        cx, cy = np.nan, np.nan
        for i in range(r * RUN, min(n, (r + 1) * RUN)):
            px, py, pz = q[i, 0], q[i, 1], q[i, 2]
            fx = (px - lo[0]) / size[0]
            fy = (py - lo[1]) / size[1]
            if fx < 0 or fy < 0 or px > hi[0] or py > hi[1]:
                continue
            bx, by = min(int(fx), nb - 1), min(int(fy), nb - 1)     # x = hi may round to bin nb: the last bin
            b = bx * nb + by
            shared = i + 1 < n and q[i + 1, 0] == px and q[i + 1, 1] == py
            if not (cached >= 0 and px == cx and py == cy) and shared:
                cx, cy = px, py                     # the ray through this point and the next: all its crossings
                cached = _ray_crossings(tri, start, bin_face, b, px, py, zs, tops, signs)
            on_ray = cached if cached >= 0 and px == cx and py == cy else -1
            out[i] = _crossings_above(tri, start, bin_face, b, px, py, pz, on_ray, zs, tops, signs)


crossings = compiled_parallel(_crossings_py)
"""The compiled :func:`_crossings_py`, its points split over the cores (None without numba)."""


def _column_crossings_py(cells, col_start, perm, o, pitch, sub, sub_index, tri, lo, hi, size, nb, start,
                         bin_face, out):  # pragma: no cover - compiled
    """:func:`_crossings_py` at the sub-cube centres of grid cells, visited column by column: the
    cells ``cells`` (c, 3) int (rotated: the ray along the last axis) grouped into columns by
    ``perm`` (c,) and ``col_start`` (columns + 1,); the point of cell ``i`` and sub-cube
    ``(a, b, k)`` is ``o + pitch * (cells[i] + (sub[a], sub[b], sub[k]))``, as numpy builds it,
    and its count goes to ``out[i, sub_index[a, b, k]]`` (``out`` zeroed). Each of a column's
    ``n_sub^2`` rays finds its crossings once for all the column's cells (a ray crossing more than
    :data:`RAY_CACHE` faces: point by point), so a column of cells costs about one cell."""
    n_sub = sub.shape[0]
    for c in prange(col_start.shape[0] - 1):
        zs = np.empty(RAY_CACHE)
        tops = np.empty(RAY_CACHE)
        signs = np.empty(RAY_CACHE)
        first = perm[col_start[c]]
        for a in range(n_sub):
            px = o[0] + pitch * (cells[first, 0] + sub[a])
            fx = (px - lo[0]) / size[0]
            for b_ in range(n_sub):
                py = o[1] + pitch * (cells[first, 1] + sub[b_])
                fy = (py - lo[1]) / size[1]
                if fx < 0 or fy < 0 or px > hi[0] or py > hi[1]:
                    continue
                b = min(int(fx), nb - 1) * nb + min(int(fy), nb - 1)   # x = hi may round to bin nb
                cached = _ray_crossings(tri, start, bin_face, b, px, py, zs, tops, signs)
                for r in range(col_start[c], col_start[c + 1]):
                    i = perm[r]
                    for kz in range(n_sub):
                        pz = o[2] + pitch * (cells[i, 2] + sub[kz])
                        out[i, sub_index[a, b_, kz]] = _crossings_above(tri, start, bin_face, b, px, py, pz, cached,
                                                                        zs, tops, signs)


column_crossings = compiled_parallel(_column_crossings_py)
"""The compiled :func:`_column_crossings_py`, its columns split over the cores (None without numba)."""


def _columns_py(key, n_keys):  # pragma: no cover - compiled
    """Rows grouped by ``key`` (n,) int in ``[0, n_keys)`` (a counting sort, stable): the rows ``perm``
    (n,) and, for the keys that occur, where their rows start in it, ``col_start`` (columns + 1,)."""
    count = np.zeros(n_keys + 1, np.int64)
    for i in range(key.shape[0]):
        count[key[i] + 1] += 1
    fill = np.cumsum(count)
    perm = np.empty(key.shape[0], np.int64)
    for i in range(key.shape[0]):
        perm[fill[key[i]]] = i
        fill[key[i]] += 1
    n_cols = 0
    for k in range(n_keys):
        if count[k + 1] > 0:
            n_cols += 1
    col_start = np.empty(n_cols + 1, np.int64)
    col_start[0] = 0
    j = 0
    acc = 0
    for k in range(n_keys):
        if count[k + 1] > 0:
            acc += count[k + 1]
            j += 1
            col_start[j] = acc
    return perm, col_start


columns = compiled(_columns_py)
"""The compiled :func:`_columns_py` (None without numba)."""


def _bin_faces_py(tri, lo, size, nb):  # pragma: no cover - compiled
    """(bin, face) pairs of every face's xy box on the ``nb x nb`` grid of cells ``size`` from ``lo``,
    grouped by bin (bin ``ix * nb + iy``), faces ascending within a bin: ``start`` (nb^2 + 1,), ``bin_face``."""
    m = tri.shape[0]
    box = np.empty((m, 4), np.int64)
    count = np.zeros(nb * nb + 1, np.int64)
    for f in range(m):
        for a in range(2):
            t0, t1, t2 = tri[f, 0, a], tri[f, 1, a], tri[f, 2, a]
            b0 = int(np.floor((min(t0, t1, t2) - lo[a]) / size[a]))
            b1 = int(np.floor((max(t0, t1, t2) - lo[a]) / size[a]))
            box[f, 2 * a] = min(max(b0, 0), nb - 1)
            box[f, 2 * a + 1] = min(max(b1, 0), nb - 1)
        for ix in range(box[f, 0], box[f, 1] + 1):
            for iy in range(box[f, 2], box[f, 3] + 1):
                count[ix * nb + iy + 1] += 1
    start = np.cumsum(count)
    fill = start[:-1].copy()
    bin_face = np.empty(start[-1], np.int64)
    for f in range(m):
        for ix in range(box[f, 0], box[f, 1] + 1):
            for iy in range(box[f, 2], box[f, 3] + 1):
                b = ix * nb + iy
                bin_face[fill[b]] = f
                fill[b] += 1
    return start, bin_face


bin_faces = compiled(_bin_faces_py)
"""The compiled :func:`_bin_faces_py` (None without numba)."""


def _rim_bounds_py(c, lo, hi, a, e, h, box, grad):  # pragma: no cover - compiled
    """For each centre ``c`` (k, 3): the distance to the nearest box ``[lo, hi]`` (f, 3) of a cone
    triangle into ``box`` (k,), and ``1/(4 pi) sum over rim edges (a, a + e) of |e| / (distance - h)^2``
    (inf when an edge comes within ``h``) into ``grad`` (k,) -- the numpy path of
    :func:`sc_fem.geometry.cellwinding._rim_bounds`, with the same arithmetic."""
    for i in prange(c.shape[0]):
        near = np.inf
        g = 0.0
        for t in range(a.shape[0]):
            d2 = 0.0
            for j in range(3):
                d = max(lo[t, j] - c[i, j], 0.0, c[i, j] - hi[t, j])
                d2 += d * d
            near = min(near, d2)
            ee = e[t, 0] * e[t, 0] + e[t, 1] * e[t, 1] + e[t, 2] * e[t, 2]
            s = ((c[i, 0] - a[t, 0]) * e[t, 0] + (c[i, 1] - a[t, 1]) * e[t, 1] + (c[i, 2] - a[t, 2]) * e[t, 2]) \
                / max(ee, 1e-300)
            s = min(max(s, 0.0), 1.0)
            r2 = 0.0
            for j in range(3):
                r = c[i, j] - a[t, j] - s * e[t, j]
                r2 += r * r
            dist = np.sqrt(r2) - h
            g += np.sqrt(ee) / (dist * dist) if dist > 0 else np.inf
        box[i] = np.sqrt(near)
        grad[i] = g / (4 * np.pi)


rim_bounds = compiled_parallel(_rim_bounds_py)
"""The compiled :func:`_rim_bounds_py` (None without numba)."""


def _area_bounds_py(c, apex, radius, area, h, out):  # pragma: no cover - compiled
    """For each centre ``c`` (k, 3): ``1/(4 pi) sum over the cone's pieces of area / (distance to the
    apex - radius - h)^2`` (inf when a piece comes within ``h``) into ``out`` (k,) -- the numpy path
    of :func:`sc_fem.geometry.cellwinding._cone_certain`'s first step, with the same arithmetic."""
    for i in prange(c.shape[0]):
        b = 0.0
        for p in range(apex.shape[0]):
            d2 = 0.0
            for j in range(3):
                d = c[i, j] - apex[p, j]
                d2 += d * d
            d = np.sqrt(d2) - radius[p] - h
            b += area[p] / (d * d) if d > 0 else np.inf
        out[i] = b / (4 * np.pi)


area_bounds = compiled_parallel(_area_bounds_py)
"""The compiled :func:`_area_bounds_py` (None without numba)."""
