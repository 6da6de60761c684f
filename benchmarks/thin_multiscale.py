"""Experiment (issue 23): multiscale cubes -- each cube's interior from an accurate fine model,
its faces tied to a degree-``p`` field.

The question this isolates: if each cube carried the exact material it holds (here: the
thin-walled box unions of ``tests/shapes.py`` meshed exactly by 27-node hexahedra), and only the
*faces between cubes* were held to a polynomial field of degree ``p`` (the cube lattice's nodes),
how close would r16 / r32 come to the conforming reference?

* ``fine``: the fine model alone (no constraint): how good the fine model is.
* ``tied``: fine DOFs on faces shared by two cubes = the coarse degree-``p`` field; every other fine
  DOF free (an upper bound of the multiscale space: its interiors keep their own inertia).
* ``condensed``: the interiors condensed statically (the coarse DOFs only, each cube's shape functions
  the fine model's static response: the multiscale finite element method).

Reproduce:

    python benchmarks/thin_multiscale.py i_beam 16 1 2 3      # case, resolution, degrees

Measured (I-section, r16, 10 lowest free-free frequencies against the P2 reference, mean / max):
the fine model (1,664 27-node hexahedra, 55k DOFs) 0.26 / 0.91 %; tied p1 40.6 / 71.4 %, p2
10.3 / 30.1 %, p3 2.55 / 6.10 %; condensed p1 41.2 / 72.8 %, p2 10.7 / 30.8 %, p3 2.81 / 6.45 %.
Only degree 3 on the shared faces lets the walls warp as they do; the static condensation costs
0.3 points over keeping the interiors' own inertia. This led to ``sc_fem.fem.multiscale``, which
makes the fine model from the mesh (voxelized finer) instead of an exact box meshing.
"""

from __future__ import annotations

import sys
import time
import warnings

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla
import scipy.linalg as sl

sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parent))
import vs_conforming_fem as vc  # noqa: E402
from thin_pfcm import lagrange_1d  # noqa: E402

import sc_fem  # noqa: E402
from sc_fem.fem.linsolve import factorize  # noqa: E402


def fine_axis(breaks: np.ndarray, hmax: float, nmin: int) -> np.ndarray:
    """Subdivide each interval between ``breaks`` into ``max(nmin, ceil(len / hmax))`` pieces."""
    out = [breaks[:1]]
    for a, b in zip(breaks[:-1], breaks[1:]):
        n = max(nmin, int(np.ceil((b - a) / hmax - 1e-9)))
        out.append(np.linspace(a, b, n + 1)[1:])
    return np.concatenate(out)


def fine_model(geo: dict, origin, h, dims, q: int, nmin: int):
    """The exact box union meshed by hexahedra on the arrangement of box and grid planes,
    each interval cut into at most ``h / q`` (at least ``nmin`` pieces)."""
    from skfem import MeshHex

    lo, hi = geo["lo"], geo["hi"]
    axes = []
    for a in range(3):
        g = origin[a] + h * np.arange(dims[a] + 1)
        b = np.r_[lo[:, a], hi[:, a]]
        b = b[(b > g[0]) & (b < g[-1])]
        br = np.unique(np.round(np.r_[g, b], 12))
        axes.append(fine_axis(br, h / q, nmin))
    m = MeshHex.init_tensor(*axes)
    mid = m.p[:, m.t].mean(axis=1)
    inside = vc._in_boxes(mid, (lo, hi))
    m = m.remove_elements(np.flatnonzero(~inside))
    return m


def assemble_fine(m, p_fine: int = 2):
    from skfem import Basis, BilinearForm, ElementHex1, ElementHex2, ElementVector, asm
    from skfem.helpers import dot
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    E, nu, rho = vc.STEEL["youngs"], vc.STEEL["poisson"], vc.STEEL["density"]
    el = ElementVector(ElementHex2() if p_fine == 2 else ElementHex1())
    basis = Basis(m, el, intorder=2 * p_fine + 1)
    K = asm(linear_elasticity(*lame_parameters(E, nu)), basis)

    @BilinearForm
    def mass(u, v, w):
        return rho * dot(u, v)

    M = asm(mass, basis)
    return basis, K.tocsr(), M.tocsr()


def tie(basis, origin, h, p: int):
    """``T`` (n_fine, n_coarse + n_free): fine DOFs on faces shared by two cubes follow the coarse
    degree-``p`` field; the others are free. Returns T and the number of coarse columns."""
    m = basis.mesh
    mid = m.p[:, m.t].mean(axis=1).T
    cell = np.floor((mid - origin) / h).astype(np.int64)                   # coarse cube of every fine element
    ucell, cube = np.unique(cell, axis=0, return_inverse=True)
    cube = cube.ravel()
    ed = basis.element_dofs                                                 # (nb, ne), vector DOFs
    n = basis.N
    lo = np.full(n, np.iinfo(np.int64).max)
    hi = np.full(n, -1)
    np.minimum.at(lo, ed.ravel(), np.broadcast_to(cube, ed.shape).ravel())
    np.maximum.at(hi, ed.ravel(), np.broadcast_to(cube, ed.shape).ravel())
    shared = lo != hi
    # one cube of each shared DOF, its reference coordinates there
    owner = np.empty(n, np.int64)
    owner[ed.ravel()] = np.broadcast_to(cube, ed.shape).ravel()
    x = basis.doflocs.T                                                     # (n, 3)
    comp = np.empty(n, np.int64)                                            # the component of each DOF
    for kind in ("nodal_dofs", "facet_dofs", "edge_dofs", "interior_dofs"):
        d = getattr(basis, kind)
        for c in range(min(3, d.shape[0])):
            comp[d[c]] = c
    sd = np.flatnonzero(shared)
    xi = (x[sd] - origin) / h - ucell[owner[sd]]
    xi = np.clip(xi, 0.0, 1.0)
    vals = [lagrange_1d(p, xi[:, a])[0] for a in range(3)]
    nb = (p + 1) ** 3
    N = np.einsum("qi,qj,qk->qijk", *vals).reshape(-1, nb)
    loc = np.stack(np.meshgrid(*[np.arange(p + 1)] * 3, indexing="ij"), -1).reshape(-1, 3)
    keys = p * ucell[owner[sd]][:, None, :] + loc[None]                     # (s, nb, 3) refined lattice
    span = keys.reshape(-1, 3).max(0) + 1
    klin = np.ravel_multi_index(keys.reshape(-1, 3).T, span).reshape(-1, nb)
    big = np.abs(N) > 1e-12
    rows = np.broadcast_to(np.arange(len(sd))[:, None], N.shape)[big]
    knode = klin[big]
    uk, col_node = np.unique(knode, return_inverse=True)
    ccol = 3 * col_node + comp[sd][rows]
    P = sp.csr_matrix((N[big], (sd[rows], ccol)), shape=(n, 3 * len(uk)))
    nc = 3 * len(uk)
    used = np.flatnonzero(np.asarray(abs(P).sum(axis=0)).ravel() > 0)
    P = P[:, used]
    G = (P.T @ P).toarray()                              # dependent columns (a face sampled by few fine DOFs)
    R, piv = sl.qr(G, mode="r", pivoting=True)
    d = np.abs(np.diag(R[0] if isinstance(R, tuple) else R))
    rank = int(np.sum(d > 1e-10 * d.max()))
    P = P[:, np.sort(piv[:rank])]                        # a spanning subset of the columns
    nc = P.shape[1]
    free = np.flatnonzero(~shared)
    F = sp.csr_matrix((np.ones(len(free)), (free, np.arange(len(free)))), shape=(n, len(free)))
    return sp.hstack([P, F]).tocsr(), nc


def lowest(K, M, k=10, rigid=6):
    sigma = -1e-3 * float(K.diagonal().mean() / M.diagonal().mean())
    lu = factorize((K - sigma * M).tocsc())
    op = sla.LinearOperator(K.shape, matvec=lu.solve, dtype=float)
    w, _ = sla.eigsh(K, k=k + rigid, M=M, sigma=sigma, OPinv=op, which="LM")
    w = np.sort(w)[rigid:]
    return np.sqrt(np.maximum(w, 0)) / (2 * np.pi)


def condensed(Kr, Mr, nc, k=10):
    Kcc, Kci = Kr[:nc, :nc], Kr[:nc, nc:]
    Kii = Kr[nc:, nc:]
    lu = factorize(Kii.tocsc())
    X = lu.solve(Kci.T.toarray())                                           # (ni, nc)
    Kc = Kcc.toarray() - Kci @ X
    Phi_i = -X
    Mcc, Mci, Mii = Mr[:nc, :nc], Mr[:nc, nc:], Mr[nc:, nc:]
    Mc = Mcc.toarray() + Mci @ Phi_i + (Mci @ Phi_i).T + Phi_i.T @ (Mii @ Phi_i)
    Kc, Mc = 0.5 * (Kc + Kc.T), 0.5 * (Mc + Mc.T)
    w = sl.eigh(Kc, Mc, eigvals_only=True, subset_by_index=[0, k + 5])
    return np.sqrt(np.maximum(np.sort(w)[6:6 + k], 0)) / (2 * np.pi)


def main(argv):
    argv = list(argv) or ["i_beam", "16", "1", "2"]
    name, r = argv[0], int(argv[1])
    degrees = [int(a) for a in argv[2:]] or [1, 2]
    q = 4
    geo = vc.thin_geometry(name)
    level = next((lv for lv in vc.THIN_REF_LEVELS[::-1] if vc._ref_cache(name, lv).exists()), None)
    ref = np.load(vc._ref_cache(name, level), allow_pickle=True)["freqs"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = sc_fem.voxelize(geo["mesh"], resolution=r, fill="solid", **vc.STEEL)
    origin, h = np.asarray(model.origin, float) * model.scale, float(model.pitch) * model.scale
    dims = np.asarray(model.cells).max(0) + 1
    t0 = time.perf_counter()
    m = fine_model(geo, origin, h, dims + 1, q, nmin=1)
    basis, K, M = assemble_fine(m)
    t1 = time.perf_counter()
    print("grid planes y:", np.round(origin[1] + h * np.arange(dims[1] + 1), 4), "z:",
          np.round(origin[2] + h * np.arange(dims[2] + 1), 4))
    print(f"{name} r{r}: fine {m.nelements} hex27, {K.shape[0]} DOFs ({t1 - t0:.1f} s); ref level {level}")

    def report(tag, f):
        err = (f - ref) / ref
        print(f"  {tag:<14} mean {100 * np.abs(err).mean():6.2f} %  max {100 * np.abs(err).max():6.2f} %   "
              + " ".join(f"{x:7.1f}" for x in f))

    print("  reference      " + " " * 30 + " ".join(f"{x:7.1f}" for x in ref))
    report("fine", lowest(K, M))
    for p in degrees:
        T, nc = tie(basis, origin, h, p)
        Kr, Mr = (T.T @ K @ T).tocsr(), (T.T @ M @ T).tocsr()
        t2 = time.perf_counter()
        report(f"tied p{p}", lowest(Kr, Mr))
        t3 = time.perf_counter()
        report(f"condensed p{p}", condensed(Kr, Mr, nc))
        t4 = time.perf_counter()
        print(f"     coarse DOFs {nc}, tied {t3 - t2:.1f} s, condensed {t4 - t3:.1f} s")


if __name__ == "__main__":
    main(sys.argv[1:])
