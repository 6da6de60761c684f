"""Experiment (issue 23): higher-order cubes (p-version finite cells) on the thin-walled cases.

Each occupied cube carries a tensor-product Lagrange field of degree ``p`` (p = 1: trilinear,
2: 27 nodes, 3: 64 nodes), continuous across cube faces, integrated **exactly** over the cube's
filled region. The thin cases are unions of axis-aligned boxes, so the filled region of each
cube is a union of sub-boxes of the arrangement of grid planes and box planes: Gauss rules on
those sub-boxes integrate the degree-2p integrands exactly. This isolates the question "does a
richer field per cube fix open-section torsion?" from the question of how to integrate over a
general mesh's content (moments of higher degree, :mod:`sc_fem.lattice.moments`).

Reproduce:

    python benchmarks/thin_pfcm.py i_beam 16 2        # case, resolution, degree (the default, ~10 s)
    python benchmarks/thin_pfcm.py i_beam 32 3 4      # ... and the shipped fine-cube rule, 4x finer

Measured (I-section, 10 lowest free-free frequencies, mean error against the P2 reference):
r16: p1 (plain Q1) 135 %, p2 48.5 %, p3 17.3 %; r32: p1 72.7 %, p2 15.4 %, p3 4.2 % (fine-cube rule:
4.9 %). Channel r32: p2 14.1 %, p3 4.7 %. Table r32 p2: 2.5 %. Portal frame r32 p2: 11.1 %.
"""

from __future__ import annotations

import sys
import time
import warnings

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parent))
import vs_conforming_fem as vc  # noqa: E402

import sc_fem  # noqa: E402
from sc_fem.fem.linsolve import factorize  # noqa: E402

EMPTY = 1e-8
"""Finite-cell stabilisation: the empty part of a cube has EMPTY times the material."""


def lagrange_1d(p: int, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Values and derivatives (len(t), p+1) of the equispaced degree-p Lagrange basis on [0, 1]."""
    nodes = np.linspace(0.0, 1.0, p + 1)
    val = np.ones((len(t), p + 1))
    der = np.zeros((len(t), p + 1))
    for j in range(p + 1):
        others = [m for m in range(p + 1) if m != j]
        den = np.prod([nodes[j] - nodes[m] for m in others])
        val[:, j] = np.prod([t - nodes[m] for m in others], axis=0) / den
        for k in others:
            der[:, j] += np.prod([t - nodes[m] for m in others if m != k], axis=0) / den
    return val, der


def arrangement(lo, hi, origin, pitch, dims):
    """Sub-boxes of the grid planes and box planes: (lower corner (n, 3), size (n, 3), filled (n,))."""
    br = []
    for a in range(3):
        g = origin[a] + pitch * np.arange(dims[a] + 1)
        b = np.r_[lo[:, a], hi[:, a]]
        b = b[(b > g[0]) & (b < g[-1])]
        br.append(np.unique(np.round(np.r_[g, b], 12)))
    L = np.stack(np.meshgrid(*[x[:-1] for x in br], indexing="ij"), -1).reshape(-1, 3)
    S = np.stack(np.meshgrid(*[np.diff(x) for x in br], indexing="ij"), -1).reshape(-1, 3)
    mid = L + S / 2
    filled = vc._in_boxes(mid.T, (lo, hi))
    return L, S, filled


def sigma_points(moments: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Six points (n, 6, 3) and weights (n, 6) per region reproducing its moments of total degree
    <= 2 (volume, centroid, second moments): ``mu +- sqrt(3 lambda_k) e_k`` with weight ``V / 6``,
    from the 27 moments (reference coordinates of each region's own cube)."""
    from sc_fem.lattice.moments import EXPONENTS

    def m(a, b, c):
        return moments[:, int(np.flatnonzero((EXPONENTS == (a, b, c)).all(1))[0])]

    V = np.maximum(m(0, 0, 0), 1e-300)
    mu = np.stack([m(1, 0, 0), m(0, 1, 0), m(0, 0, 1)], 1) / V[:, None]
    E = np.empty((len(V), 3, 3))
    for i in range(3):
        for j in range(3):
            e = [0, 0, 0]
            e[i] += 1
            e[j] += 1
            E[:, i, j] = m(*e) / V
    C = E - mu[:, :, None] * mu[:, None, :]
    lam, vec = np.linalg.eigh(C)
    off = vec * np.sqrt(3.0 * np.maximum(lam, 0.0))[:, None, :]           # columns: the offsets
    pts = np.concatenate([mu[:, None, :] + off.transpose(0, 2, 1), mu[:, None, :] - off.transpose(0, 2, 1)], 1)
    return pts, np.repeat(V[:, None] / 6.0, 6, axis=1)


def fine_quadrature(geo: dict, model, s: int):
    """Quadrature over each cube's filled region from a model voxelized ``s`` times finer: six
    sigma points per fine cube (its exact moments of degree <= 2). Returns (element (q,),
    reference coordinates in the coarse cube (q, 3), weight (q,), m^3)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fine = sc_fem.voxelize(geo["mesh"], pitch=model.pitch / s, fill="solid", keep="all", **vc.STEEL)
    parent = fine.cells // s
    key_c = np.ravel_multi_index(model.cells.T, model.dims)
    ok = np.all(parent < model.dims, axis=1)
    at = np.searchsorted(key_c, np.ravel_multi_index(parent[ok].T, model.dims))
    at = np.minimum(at, len(key_c) - 1)
    hit = np.flatnonzero(ok)[key_c[at] == np.ravel_multi_index(parent[ok].T, model.dims)]
    e = at[key_c[at] == np.ravel_multi_index(parent[ok].T, model.dims)]
    pts, w = sigma_points(fine.moments[hit])
    local = (fine.cells[hit] - s * parent[hit])[:, None, :]
    xi = (local + pts) / s
    hf = float(fine.pitch * fine.scale)
    return np.repeat(e, 6), xi.reshape(-1, 3), (w * hf ** 3).ravel()


def build(geo: dict, r: int, p: int, fine_s: int = 0):
    mesh = geo["mesh"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = sc_fem.voxelize(mesh, resolution=r, fill="solid", **vc.STEEL)
    origin, h = np.asarray(model.origin, float), float(model.pitch)
    cells = np.asarray(model.cells, np.int64)
    dims = cells.max(0) + 1
    L, S, filled = arrangement(geo["lo"], geo["hi"], origin, h, dims)
    cell_of = np.floor((L + S / 2 - origin) / h).astype(np.int64)
    lin = np.ravel_multi_index(cell_of.T, dims)
    cube_lin = np.ravel_multi_index(cells.T, dims)
    pos = -np.ones(np.prod(dims), np.int64)
    pos[cube_lin] = np.arange(len(cells))
    e_of = pos[lin]
    keep = e_of >= 0
    L, S, filled, e_of = L[keep], S[keep], filled[keep], e_of[keep]
    weight = np.where(filled, 1.0 if not fine_s else 0.0, EMPTY)
    # Gauss points on each sub-box, in the cube's reference frame
    g, w = np.polynomial.legendre.leggauss(p + 1)
    g, w = 0.5 * (g + 1), 0.5 * w
    G = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    W = np.einsum("i,j,k->ijk", w, w, w).ravel()
    x = L[:, None, :] + S[:, None, :] * G[None]                                   # (s, q, 3)
    xi = (x - origin) / h - cells[e_of][:, None, :]
    wq = (np.prod(S, 1) * weight)[:, None] * W[None]                              # (s, q) m^3
    xi, wq = xi.reshape(-1, 3), wq.ravel()
    eq = np.repeat(e_of, len(W))
    if fine_s:                     # the material from the finer model's sigma points instead
        e2, xi2, w2 = fine_quadrature(geo, model, fine_s)
        eq, xi, wq = np.r_[eq, e2], np.vstack([xi, xi2]), np.r_[wq, w2]
    nb = (p + 1) ** 3
    vals, ders = zip(*[lagrange_1d(p, xi[:, a]) for a in range(3)])
    N = np.einsum("qi,qj,qk->qijk", vals[0], vals[1], vals[2]).reshape(-1, nb)
    dN = np.stack([np.einsum("qi,qj,qk->qijk", ders[0], vals[1], vals[2]),
                   np.einsum("qi,qj,qk->qijk", vals[0], ders[1], vals[2]),
                   np.einsum("qi,qj,qk->qijk", vals[0], vals[1], ders[2])], 1).reshape(-1, 3, nb) / h
    E, nu, rho = vc.STEEL["youngs"], vc.STEEL["poisson"], vc.STEEL["density"]
    lam, mu = E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))
    ne = len(cells)
    Gm = np.zeros((ne, 3, 3, nb, nb))
    Mm = np.zeros((ne, nb, nb))
    for s in range(0, len(xi), 20000):
        sl = slice(s, s + 20000)
        contrib = np.einsum("q,qai,qbj->qabij", wq[sl], dN[sl], dN[sl])
        np.add.at(Gm, eq[sl], contrib)
        np.add.at(Mm, eq[sl], np.einsum("q,qi,qj->qij", wq[sl], N[sl], N[sl]))
    K = lam * np.einsum("ecdij->eicjd", Gm) + mu * np.einsum("eaaij,cd->eicjd", Gm, np.eye(3)) \
        + mu * np.einsum("edcij->eicjd", Gm)
    K = K.reshape(ne, 3 * nb, 3 * nb)
    Me = rho * np.einsum("eij,cd->eicjd", Mm, np.eye(3)).reshape(ne, 3 * nb, 3 * nb)
    loc = np.stack(np.meshgrid(*[np.arange(p + 1)] * 3, indexing="ij"), -1).reshape(-1, 3)
    keys = p * cells[:, None, :] + loc[None]                                      # (e, nb, 3)
    kd = dims * p + 1
    klin = np.ravel_multi_index(keys.reshape(-1, 3).T, kd)
    uniq, node = np.unique(klin, return_inverse=True)
    node = node.reshape(ne, nb)
    dofs = (3 * node[:, :, None] + np.arange(3)).reshape(ne, -1)
    n = 3 * len(uniq)
    rows = np.repeat(dofs, 3 * nb, axis=1).ravel()
    cols = np.tile(dofs, (1, 3 * nb)).ravel()
    Kg = sp.csr_matrix((K.ravel(), (rows, cols)), shape=(n, n))
    Mg = sp.csr_matrix((Me.ravel(), (rows, cols)), shape=(n, n))
    return model, Kg, Mg, float(Me.sum() / 3)


def freqs(K, M, k=10):
    sigma = -1.0
    lu = factorize((K - sigma * M).tocsc())
    op = sla.LinearOperator(K.shape, matvec=lu.solve, dtype=float)
    w, _ = sla.eigsh(K, k=k + 6, M=M, sigma=sigma, OPinv=op, which="LM")
    w = np.sort(w)[6:]
    return np.sqrt(np.maximum(w, 0)) / (2 * np.pi)


def main(argv):
    argv = list(argv) or ["i_beam", "16", "2"]               # `make bench`: the quick case
    name, r, p = argv[0], int(argv[1]), int(argv[2])
    fine_s = int(argv[3]) if len(argv) > 3 else 0
    geo = vc.thin_geometry(name)
    level = next((lv for lv in vc.THIN_REF_LEVELS[::-1] if vc._ref_cache(name, lv).exists()), None)
    if level is None:
        raise SystemExit(f"no P2 reference of {name!r} is cached: run "
                         f"`python benchmarks/vs_conforming_fem.py --thin --cases {name}` first")
    ref = np.load(vc._ref_cache(name, level), allow_pickle=True)["freqs"]
    t0 = time.perf_counter()
    model, K, M, mass = build(geo, r, p, fine_s)
    t1 = time.perf_counter()
    f = freqs(K, M)
    t2 = time.perf_counter()
    err = (f - ref) / ref
    print(f"{name} r{r} p{p} fine{fine_s} (reference level {level}): cubes {model.n_cubes} dofs {K.shape[0]} mass {mass:.4f} "
          f"build {t1 - t0:.1f}s eig {t2 - t1:.1f}s")
    print("  f   ", np.round(f, 1))
    print("  ref ", np.round(ref, 1))
    print(f"  mean |err| {100 * np.abs(err).mean():.1f} %  max {100 * np.abs(err).max():.1f} %")


if __name__ == "__main__":
    main(sys.argv[1:])
