"""The eigenpairs of a plate operator below a bound, by shift-invert slices planned with Sylvester's inertia.

- Ordering: the free dofs in a geometric nested dissection of the node grid (the plate's mesh is a regular
  grid: halve the longer side by a line of nodes, recursively; separators last, a node's three fields
  together). Its LU (SuperLU, natural order, diagonal pivots) has the fill of a minimum-degree ordering but
  larger supernodes: factor and solve ~1.5-2.5x faster on the bundled twin's mesh (docs/findings.md).
- Inertia: with diagonal pivots the LU of (A - b I) is L D L^T up to scaling, so its negative pivots count the
  eigenvalues below b exactly. The band [shift, lam_max] is cut into intervals holding about SLICE_TARGET
  eigenvalues each (a first guess from the Weyl law of a plate, N ~ omega, then intervals split until their
  counts fit), and every interval's count is known before any eigenvector is computed.
- Slices: the interval [lo, hi) with c eigenvalues is solved by eigsh with sigma at its midpoint and k = c +
  a guard: the c nearest eigenvalues to the midpoint are the interval's. Every interval must return exactly its
  count (else the slice is redone with a wider guard). No overlap is computed twice, and the slices are
  independent: they run through the batch executor (processes here, or a Dask cluster).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

SLICE_TARGET = 100      # eigenpairs per slice (Lanczos memory ~ 2 x this x dofs x 8 bytes)
EIGSH_TOL = 1e-9        # ARPACK's relative tolerance (shapes are stored as float32)


def nested_dissection(nx: int, ny: int) -> np.ndarray:
    """Node numbers (node = j (nx + 1) + i) of an (nx + 1) x (ny + 1) grid in nested-dissection order."""
    parts = []

    def split(i0, i1, j0, j1):
        ni, nj = i1 - i0, j1 - j0
        if ni <= 0 or nj <= 0:
            return
        if ni * nj <= 64:
            jj, ii = np.meshgrid(np.arange(j0, j1), np.arange(i0, i1), indexing="ij")
            parts.append((jj * (nx + 1) + ii).ravel())
            return
        if ni >= nj:
            m = i0 + ni // 2
            split(i0, m, j0, j1)
            split(m + 1, i1, j0, j1)
            parts.append(np.arange(j0, j1) * (nx + 1) + m)
        else:
            m = j0 + nj // 2
            split(i0, i1, j0, m)
            split(i0, i1, m + 1, j1)
            parts.append(m * (nx + 1) + np.arange(i0, i1))

    split(0, nx + 1, 0, ny + 1)
    return np.concatenate(parts)


def dof_order(nx: int, ny: int, free: np.ndarray) -> np.ndarray:
    """Positions in `free` (dof = field x nodes + node) in nested-dissection order, a node's fields together."""
    nn = (nx + 1) * (ny + 1)
    dofs = (nested_dissection(nx, ny)[:, None] + nn * np.arange(3)[None, :]).ravel()
    pos = np.full(3 * nn, -1)
    pos[free] = np.arange(free.size)
    order = pos[dofs]
    return order[order >= 0]


def factor(a: sp.csr_matrix, sigma: float):
    """SuperLU of (a - sigma I) in a's own order (a already nested-dissection ordered), diagonal pivots."""
    return spla.splu((a - sigma * sp.eye(a.shape[0], format="csr")).tocsc(), permc_spec="NATURAL",
                     diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))


def count_below(a: sp.csr_matrix, b: float) -> int:
    """Eigenvalues of the symmetric a below b (Sylvester: the negative pivots of a - b I = L D L^T)."""
    lu = factor(a, b)
    if not (np.array_equal(lu.perm_r, np.arange(a.shape[0])) and np.array_equal(lu.perm_c, lu.perm_r)):
        raise RuntimeError("inertia: the factorisation pivoted off the diagonal")
    return int(np.count_nonzero(lu.U.diagonal() < 0))


def _count_task(task):
    a, b = task
    return count_below(a, b)


def _slice_task(task):
    """The eigenpairs of a in [lo, hi) (exactly `count` of them): eigsh around the midpoint."""
    a, lo, hi, count = task
    sigma = 0.5 * (lo + hi)
    lu = factor(a, sigma)
    op = spla.LinearOperator(a.shape, matvec=lu.solve, dtype=float)
    guard = max(8, count // 8)
    for _ in range(3):
        k = min(count + guard, a.shape[0] - 2)
        lam, vec = spla.eigsh(a, k=k, sigma=sigma, which="LM", OPinv=op, tol=EIGSH_TOL)
        keep = (lam >= lo) & (lam < hi)
        if keep.sum() == count or k >= a.shape[0] - 2:
            break
        guard *= 2
    return lam[keep], vec[:, keep]


def plan(a: sp.csr_matrix, lo: float, hi: float, executor, target: int = SLICE_TARGET) -> list:
    """Intervals [(lo_i, hi_i, count_i)] covering [lo, hi) with counts <= 1.5 x target (module doc)."""
    n_lo, n_hi = executor.map(_count_task, [(a, lo), (a, hi)])
    bounds = {lo: n_lo, hi: n_hi}
    todo = [(lo, hi)]
    while todo:
        # Weyl for a plate: N ~ omega, so cut each interval evenly in sqrt(lambda)
        cuts = []
        for b0, b1 in todo:
            n = bounds[b1] - bounds[b0]
            pieces = max(1, math.ceil(n / target))
            w0, w1 = math.sqrt(max(b0, 0.0)), math.sqrt(b1)
            cuts += [(w0 + (w1 - w0) * p / pieces) ** 2 for p in range(1, pieces)]
        cuts = [c for c in cuts if c not in bounds]
        for c, n in zip(cuts, executor.map(_count_task, [(a, c) for c in cuts])):
            bounds[c] = n
        edges = sorted(bounds)
        todo = [(b0, b1) for b0, b1 in zip(edges[:-1], edges[1:])
                if bounds[b1] - bounds[b0] > 1.5 * target and (b1 - b0) > 1e-9 * b1]
    edges = sorted(bounds)
    return [(b0, b1, bounds[b1] - bounds[b0]) for b0, b1 in zip(edges[:-1], edges[1:]) if bounds[b1] > bounds[b0]]


def spectrum(a: sp.csr_matrix, order: np.ndarray, lam_max: float, shift: float, executor, progress=None):
    """Eigenpairs of the symmetric a with eigenvalues in [shift, lam_max], ascending: (lam, vec [n, modes]) in
    a's own dof order. `order`: a's dofs in nested-dissection order; `executor`: runs the slices."""
    ap = a[order][:, order].tocsr()
    # the top bound just above lam_max: an eigenvalue on it is kept by the caller's <= test
    intervals = plan(ap, shift, lam_max * (1 + 1e-12), executor)
    lams, vecs = [], []
    for (lo, hi, count), (lam, vec) in zip(intervals, executor.map(_slice_task, [(ap, lo, hi, c)
                                                                                  for lo, hi, c in intervals])):
        lams.append(lam)
        vecs.append(vec)
        if progress:
            progress(hi)
    lam = np.concatenate(lams) if lams else np.zeros(0)
    expected = sum(c for _, _, c in intervals)
    if lam.size != expected:
        raise RuntimeError(f"modal basis: the slices found {lam.size} eigenpairs where the inertia counts "
                           f"{expected}")
    vec_p = np.concatenate(vecs, axis=1) if vecs else np.zeros((a.shape[0], 0))
    vec = np.empty_like(vec_p)
    vec[order] = vec_p
    idx = np.argsort(lam)
    return lam[idx], vec[:, idx]


def shifted_solver(a: sp.csr_matrix, order: np.ndarray, sigma: float):
    """X -> (a - sigma I)^-1 X for blocks X [n, r] in a's own order (the nested-dissection LU)."""
    lu = factor(a[order][:, order].tocsr(), sigma)

    def solve(x):
        x = np.asarray(x, float)
        y = np.empty_like(x)
        y[order] = lu.solve(np.ascontiguousarray(x[order]))
        return y
    return solve
