"""The plate's modes from the finite-element model's own stiffness and mass (the reduced-order twin's basis).

- K is probed from the C++ kernel (`Plate.internal_force_double`, node springs included) with 9 node colours x
  3 fields: nodes of one colour are 3 apart, so their stencils do not overlap and each probe yields whole
  columns. No element physics is written again in Python. M is the model's lumped mass (w, beta_x, beta_y).
- Modes of K phi = omega^2 M phi on the free dofs by shift-invert Lanczos (scipy.sparse.linalg.eigsh on
  M^-1/2 K M^-1/2) in slices: a slice centred at sigma returns the k eigenvalues nearest sigma, so every
  eigenvalue closer to sigma than the farthest one found is in it; the next slice is centred so that its
  covered interval overlaps the last one's, and only eigenvalues past the last trusted one are kept.
- Residual flexibility: the modes above the cut-off still respond quasi-statically to the ball, so the
  contact sees the static flexibility of the truncated modes, R(a, b) = [K_s^-1 - Phi (Lambda - s)^-1
  Phi^T](w_a, w_b) (K_s = K - s M, s < 0 a small shift: defined for free plates too). It is local (the kept
  modes carry the long-range part), so it is probed: unit loads on the w of every node of one colour (nodes
  `PROBE_SPACING` apart), one sparse solve per colour, and the value read at each node and its neighbours of
  the same element. Stored per node for the offsets (0,0), (1,0), (0,1), (1,1), (1,-1).
- Cache: on disk, keyed by a hash of everything that enters K / k_ref and M (mesh, per-element stiffness
  ratios, material ratios, masses, supports, springs, the cut-off in units of the stiffness scale) and
  of the sensor functionals' node set. A uniform stiffness scale (E for a plate whose every stiffness scales
  with it) reuses the basis: the shapes are unchanged and omega scales with sqrt(scale).
- Memory: the mode shapes are kept as float32 w at every node [nodes, modes] (memory-mapped from the cache)
  plus float32 beta_x, beta_y at the sensor functionals' nodes; `ModalBasis.nbytes` states it.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from ..errors import ConfigError
from . import modal_slices
from .executor import Executor
from .model import Model, support_masks

FORMAT_VERSION = 2
PROBE_WAVELENGTHS = 2.5     # residual probes of one colour this many A0 wavelengths (at the cut-off) apart


ARRAYS = ("omega", "w_nodes", "beta_nodes", "beta_index", "residual", "out_residual", "out_functionals")


def cache_dir() -> Path:
    env = os.environ.get("IMPACTSENSE_MODAL_CACHE")
    if env:
        return Path(env)
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "impactsense" / "modal"


def default_cutoff(model: Model) -> float:
    """SimParams.modal_cutoff_factor x the band the FEM resolves (f_max, Eq. 1)."""
    return float(model.params.modal_cutoff_factor * model.f_max_hz)


# ----- operators of the finite-element model -----

def assembled_stiffness(plate, nx: int, ny: int) -> sp.csr_matrix:
    """K [3 nodes, 3 nodes] (dof = field * nodes + node; fields w, beta_x, beta_y) of the C++ operator,
    made symmetric to round-off (the probed operator's symmetry is checked by the tests)."""
    k = probed_stiffness(plate, nx, ny)
    return (k + k.T) * 0.5


def probed_stiffness(plate, nx: int, ny: int) -> sp.csr_matrix:
    """K of the C++ operator as the kernel applies it: probed with 9 node colours x 3 fields (nodes of one
    colour are 3 apart, so their stencils do not overlap)."""
    nn = (nx + 1) * (ny + 1)
    jj, ii = np.divmod(np.arange(nn), nx + 1)
    rows, cols, vals = [], [], []
    for ci in range(3):
        for cj in range(3):
            sel = np.flatnonzero((ii % 3 == ci) & (jj % 3 == cj))
            for field in range(3):
                u = np.zeros((3, nn))
                u[field, sel] = 1
                f = np.asarray(plate.internal_force_double(u))
                for di in (-1, 0, 1):
                    for dj in (-1, 0, 1):
                        ni, nj = ii[sel] + di, jj[sel] + dj
                        ok = (ni >= 0) & (ni <= nx) & (nj >= 0) & (nj <= ny)
                        src, dst = sel[ok], nj[ok] * (nx + 1) + ni[ok]
                        for g in range(3):
                            v = f[g, dst]
                            nz = v != 0
                            rows.append(g * nn + dst[nz])
                            cols.append(field * nn + src[nz])
                            vals.append(v[nz])
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * nn, 3 * nn))


def fixed_dofs(model: Model) -> np.ndarray:
    masks = support_masks(model.nx, model.ny, model.params.support)
    return np.concatenate([m.ravel() for m in masks]).astype(bool)


def lumped_mass(model: Model) -> np.ndarray:
    return np.concatenate([model.mass_w, model.mass_r, model.mass_r])


def stiffness_reference(model: Model) -> float:
    """The scalar the cached K is normalised by: the bare plate's bending stiffness."""
    from .material import element_constants

    return float(element_constants(model.params)[0])


# ----- the basis -----

@dataclass
class ModalBasis:
    omega: np.ndarray          # natural frequencies [rad/s] at this model's stiffness, float64 [modes]
    w_nodes: np.ndarray        # mass-normalised w at every node, float32 [nodes, modes]
    beta_nodes: np.ndarray     # beta_x, beta_y at `beta_index` nodes, float32 [2, n, modes]
    beta_index: np.ndarray     # node numbers of beta_nodes' rows (sorted)
    residual: np.ndarray       # residual flexibility [m/N] per node: offsets (0,0), (1,0), (0,1), (1,1), (1,-1)
    out_residual: np.ndarray   # the sensors' residual output for a unit force on w at each node [sensors, nodes]
    out_functionals: np.ndarray  # the sensor functionals it was computed for, dense at beta_index [S, 2, n]
    cutoff_hz: float
    key: str
    stiffness_scale: float = 1.0

    @property
    def modes(self) -> int:
        return self.omega.size

    @property
    def nbytes(self) -> int:
        return int(self.w_nodes.nbytes + self.beta_nodes.nbytes + self.residual.nbytes + self.omega.nbytes
                   + self.out_residual.nbytes + self.out_functionals.nbytes)

    def scaled(self, scale: float) -> "ModalBasis":
        """The basis of the same model with every stiffness x scale (shapes unchanged)."""
        return ModalBasis(self.omega * math.sqrt(scale), self.w_nodes, self.beta_nodes, self.beta_index,
                          self.residual / scale, self.out_residual / scale, self.out_functionals,
                          self.cutoff_hz * math.sqrt(scale), self.key, self.stiffness_scale * scale)

    def _dense(self, sensors) -> np.ndarray:
        """Sensor functionals as dense weights on beta_x, beta_y at beta_index nodes [S, 2, n]."""
        out = np.zeros((len(sensors), 2, self.beta_index.size))
        for s, (nodes, wx, wy) in enumerate(sensors):
            nodes = np.asarray(nodes, np.int64)
            pos = np.searchsorted(self.beta_index, nodes)
            if np.any(pos >= self.beta_index.size) or \
                    np.any(self.beta_index[np.minimum(pos, self.beta_index.size - 1)] != nodes):
                raise ConfigError("modal basis: a sensor functional reaches nodes outside the cached sensor nodes")
            np.add.at(out[s, 0], pos, np.asarray(wx, float))
            np.add.at(out[s, 1], pos, np.asarray(wy, float))
        return out

    def output_scales(self, sensors) -> np.ndarray:
        """Each sensor functional as a multiple of the one out_residual was computed for [S] (the PZT
        constants scale a functional; its shape is geometry and part of the cache key)."""
        cur = self._dense(sensors).reshape(len(sensors), -1)
        ref = self.out_functionals.reshape(len(sensors), -1)
        ratio = np.sum(cur * ref, axis=1) / np.sum(ref * ref, axis=1)
        if np.any(np.abs(cur - ratio[:, None] * ref).max(axis=1) > 1e-6 * np.abs(cur).max(axis=1)):
            raise ConfigError("modal basis: the sensor functionals differ in shape from the cached ones")
        return ratio

    def sensor_gains(self, sensors) -> np.ndarray:
        """Each sensor functional (node, wx, wy) applied to every mode: [n_sensors, modes] float64."""
        dense = self._dense(sensors)
        return dense[:, 0] @ self.beta_nodes[0].astype(float) + dense[:, 1] @ self.beta_nodes[1].astype(float)

    def contact(self, model: Model, x_m: np.ndarray, y_m: np.ndarray):
        """Mode shapes at the contact points (bilinear, as the FEM's contact) [n, modes] float64, the
        residual flexibility there [n] and the sensors' residual output per unit force there [n, sensors]."""
        nx, ny = model.nx, model.ny
        i = np.minimum((x_m / model.hx_m).astype(int), nx - 1)
        j = np.minimum((y_m / model.hy_m).astype(int), ny - 1)
        xi, eta = x_m / model.hx_m - i, y_m / model.hy_m - j
        r = nx + 1
        n00, n10, n11, n01 = j * r + i, j * r + i + 1, (j + 1) * r + i + 1, (j + 1) * r + i
        w00, w10, w11, w01 = (1 - xi) * (1 - eta), xi * (1 - eta), xi * eta, (1 - xi) * eta
        phi = np.zeros((x_m.size, self.modes))
        for nd, wt in ((n00, w00), (n10, w10), (n11, w11), (n01, w01)):
            phi += wt[:, None] * self.w_nodes[nd].astype(float)
        res = self.residual
        diag = (w00 ** 2 * res[0, n00] + w10 ** 2 * res[0, n10] + w11 ** 2 * res[0, n11] + w01 ** 2 * res[0, n01])
        off = 2 * (w00 * w10 * res[1, n00] + w01 * w11 * res[1, n01]       # along x
                   + w00 * w01 * res[2, n00] + w10 * w11 * res[2, n10]     # along y
                   + w00 * w11 * res[3, n00] + w01 * w10 * res[4, n01])    # diagonals
        out = sum(wt[:, None] * self.out_residual[:, nd].T for nd, wt in ((n00, w00), (n10, w10), (n11, w11),
                                                                         (n01, w01)))
        return phi, diag + off, out


def _basis_key(model: Model, k: sp.csr_matrix, k_ref: float, mass: np.ndarray, fixed: np.ndarray,
               cutoff_rel: float, beta_index: np.ndarray, shapes: np.ndarray) -> str:
    h = hashlib.sha256()
    h.update(json.dumps(dict(v=FORMAT_VERSION, nx=model.nx, ny=model.ny, hx=model.hx_m, hy=model.hy_m,
                             probe=PROBE_WAVELENGTHS, cutoff_rel=round(cutoff_rel, 9))).encode())
    kn = k.tocoo()
    for arr in (kn.row.astype(np.int64), kn.col.astype(np.int64), (kn.data / k_ref).astype(np.float32),
                mass.astype(np.float32), fixed, beta_index, shapes.astype(np.float32)):
        h.update(np.ascontiguousarray(arr).tobytes())
    return h.hexdigest()[:32]


def _sensor_nodes(model: Model) -> np.ndarray:
    return np.unique(np.concatenate([np.asarray(s[0], np.int64) for s in model.sensors]))


def probe_spacing(model: Model, cutoff_hz: float) -> int:
    """Nodes between residual probes of one colour: PROBE_WAVELENGTHS A0 wavelengths at the cut-off."""
    from .model import mesh_element_m

    wavelength = 10 * mesh_element_m(model.params, cutoff_hz)
    return max(4, int(math.ceil(PROBE_WAVELENGTHS * wavelength / min(model.hx_m, model.hy_m))))


RESIDUAL_BLOCK = 64   # probe right-hand sides solved at once (a block solve is ~2x cheaper per vector)


def _residual(model: Model, solve, m_free, free, lam, vec_free, shift, spacing, functionals):
    """Residual flexibility of the truncated modes on w, per node and in-element offset (module doc), and the
    sensors' residual output for a unit force on each node's w (by reciprocity: the static w under the sensor
    functional as a load, less its kept modes) [S, nodes]. solve: X -> (A - s I)^-1 X, A = M^-1/2 K M^-1/2."""
    nx, ny = model.nx, model.ny
    nn = (nx + 1) * (ny + 1)
    jj, ii = np.divmod(np.arange(nn), nx + 1)
    m_isqrt = 1 / np.sqrt(m_free)
    phi = vec_free / np.sqrt(m_free)[:, None]           # mass-normalised shapes on the free dofs
    pos = np.full(3 * nn, -1)
    pos[free] = np.arange(free.size)
    w_pos = pos[:nn]

    def static(rhs):                                     # (K - s M)^-1 rhs
        return m_isqrt[:, None] * solve(m_isqrt[:, None] * rhs)

    inv_gap = 1 / (lam - shift)
    colours = [np.flatnonzero((ii % spacing == ci) & (jj % spacing == cj) & (w_pos >= 0))
               for ci in range(spacing) for cj in range(spacing)]
    colours = [c for c in colours if c.size]
    out = np.zeros((5, nn))
    offsets = ((0, 0), (1, 0), (0, 1), (1, 1), (1, -1))
    for b0 in range(0, len(colours), RESIDUAL_BLOCK):
        block = colours[b0:b0 + RESIDUAL_BLOCK]
        rhs = np.zeros((free.size, len(block)))
        for c, sel in enumerate(block):
            rhs[w_pos[sel], c] = 1.0
        ys = static(rhs)
        for c, sel in enumerate(block):
            coef = phi[w_pos[sel]].sum(axis=0) * inv_gap     # the kept modes' part, read only where needed
            for o, (di, dj) in enumerate(offsets):
                ni, nj = ii[sel] + di, jj[sel] + dj
                ok = (ni >= 0) & (ni <= nx) & (nj >= 0) & (nj <= ny)
                dst = nj[ok] * (nx + 1) + ni[ok]
                good = w_pos[dst] >= 0
                rows = w_pos[dst[good]]
                out[o, sel[ok][good]] = ys[rows, c] - phi[rows] @ coef
    beta_index = _sensor_nodes(model)
    loads = np.zeros((3 * nn, functionals.shape[0]))
    loads[nn + beta_index] = functionals[:, 0].T
    loads[2 * nn + beta_index] = functionals[:, 1].T
    rhs = loads[free]
    ys = static(rhs) - phi @ ((phi.T @ rhs) * inv_gap[:, None])
    out_res = np.zeros((functionals.shape[0], nn))
    w_free = w_pos >= 0
    out_res[:, w_free] = ys[w_pos[w_free]].T
    return out, out_res


def compute_basis(model: Model, cutoff_hz: float | None = None, *, k=None, progress=None,
                  workers: int = 2) -> ModalBasis:
    """The modes of `model` up to cutoff_hz (default: `default_cutoff`) and the residual flexibility; the
    spectrum's slices run `workers` at a time (or on the process's Dask cluster, executor.set_scheduler)."""
    cutoff_hz = default_cutoff(model) if cutoff_hz is None else float(cutoff_hz)
    k = assembled_stiffness(model.plate, model.nx, model.ny) if k is None else k
    mass = lumped_mass(model)
    fixed = fixed_dofs(model)
    free = np.flatnonzero(~fixed)
    k_free = k[free][:, free].tocsr()
    m_free = mass[free]
    dm = sp.diags(1 / np.sqrt(m_free))
    a = (dm @ k_free @ dm).tocsr()
    lam_max = (2 * np.pi * cutoff_hz) ** 2
    # a shift below the spectrum: a few percent of the lowest Kirchhoff-like eigenvalue scale, negative
    diag_scale = float(np.median(a.diagonal()))
    shift = -1e-6 * diag_scale
    order = modal_slices.dof_order(model.nx, model.ny, free)
    lam, vec = modal_slices.spectrum(a, order, lam_max, shift, Executor(workers=workers, kind="processes"),
                                     progress)
    sel = lam <= lam_max
    lam, vec = np.maximum(lam[sel], 0.0), vec[:, sel]
    nn = model.nodes
    beta_index = _sensor_nodes(model)
    empty = ModalBasis(np.zeros(0), np.zeros((0, 0), np.float32), np.zeros((2, 0, 0), np.float32), beta_index,
                       np.zeros(0), np.zeros(0), np.zeros(0), 0.0, "")
    functionals = empty._dense(model.sensors)
    res, out_res = _residual(model, modal_slices.shifted_solver(a, order, shift), m_free, free, lam, vec, shift,
                             probe_spacing(model, cutoff_hz), functionals)
    full = np.zeros((3 * nn, lam.size))
    full[free] = vec / np.sqrt(m_free)[:, None]
    return ModalBasis(omega=np.sqrt(lam), w_nodes=full[:nn].astype(np.float32),
                      beta_nodes=np.stack([full[nn + beta_index], full[2 * nn + beta_index]]).astype(np.float32),
                      beta_index=beta_index, residual=res, out_residual=out_res, out_functionals=functionals,
                      cutoff_hz=cutoff_hz, key="")


MAX_BASIS_MB = 2048   # refuse a basis whose float32 shapes would exceed this (IMPACTSENSE_MODAL_MAX_MB)


def estimated_modes(model: Model, cutoff_hz: float) -> int:
    """Modes below cutoff_hz: Kirchhoff's count A sqrt(rho t / D) omega / (4 pi) along the softest direction,
    x 3 (the Mindlin plate and a coarse mesh count more: 1.6 x on the bundled twin's mesh, 2.8 x on 5 mm)."""
    from .material import softest

    p = model.params
    t = p.thickness_mm * 1e-3
    d = softest(p)[0] if p.e2_pa is not None else p.e_pa * t ** 3 / (12 * (1 - p.nu ** 2))
    area = model.lx_m * model.ly_m
    return int(3 * area * math.sqrt(p.rho_kg_m3 * t / d) * 2 * math.pi * cutoff_hz / (4 * math.pi)) + 1


def check_size(model: Model, cutoff_hz: float) -> None:
    limit = float(os.environ.get("IMPACTSENSE_MODAL_MAX_MB", MAX_BASIS_MB))
    mb = estimated_modes(model, cutoff_hz) * model.nodes * 4 / 2 ** 20
    if mb > limit:
        raise ConfigError(f"the modal basis of this plate would take ~{mb:.0f} MB (float32 w of ~"
                          f"{estimated_modes(model, cutoff_hz)} modes at {model.nodes} nodes; limit {limit:.0f} MB, "
                          "IMPACTSENSE_MODAL_MAX_MB): use --solver direct or a smaller modal_cutoff_factor")


MAX_CACHED = 8   # bases kept on disk (the least recently used go first); ~190 MB for the bundled twin's


def _prune(root: Path) -> None:
    """Keeps the MAX_CACHED - 1 most recently used bases (a basis' meta.json is touched when it is loaded)."""
    if not root.is_dir():
        return
    import shutil

    entries = sorted((f for f in root.glob("basis-*") if (f / "meta.json").is_file()),
                     key=lambda f: (f / "meta.json").stat().st_mtime, reverse=True)
    for old in entries[MAX_CACHED - 1:]:
        shutil.rmtree(old, ignore_errors=True)


def _cache_key(model: Model, cutoff_hz: float):
    """(K, k_ref, key) of the basis of `model` up to cutoff_hz."""
    k = assembled_stiffness(model.plate, model.nx, model.ny)
    k_ref = stiffness_reference(model)
    beta_index = _sensor_nodes(model)
    # the cut-off relative to the stiffness scale: the same relative band is the same basis
    cutoff_rel = cutoff_hz / math.sqrt(k_ref)
    empty = ModalBasis(np.zeros(0), np.zeros((0, 0), np.float32), np.zeros((2, 0, 0), np.float32), beta_index,
                       np.zeros(0), np.zeros(0), np.zeros(0), 0.0, "")
    dense = empty._dense(model.sensors)
    shapes = dense / np.abs(dense).reshape(dense.shape[0], -1).max(axis=1)[:, None, None]   # geometry only
    key = _basis_key(model, k, k_ref, lumped_mass(model), fixed_dofs(model), cutoff_rel, beta_index, shapes)
    return k, k_ref, key


def is_cached(model: Model, cutoff_hz: float | None = None) -> bool:
    """True if the basis of `model` (up to a uniform stiffness scale) is in the disk cache."""
    cutoff_hz = default_cutoff(model) if cutoff_hz is None else float(cutoff_hz)
    return (cache_dir() / f"basis-{_cache_key(model, cutoff_hz)[2]}" / "meta.json").is_file()


def load_or_compute(model: Model, cutoff_hz: float | None = None, *, use_cache: bool = True,
                    progress=None) -> ModalBasis:
    """The basis of `model`, from the disk cache when the same plate (up to a uniform stiffness scale) was
    solved before."""
    from ..outputs import atomic_file

    cutoff_hz = default_cutoff(model) if cutoff_hz is None else float(cutoff_hz)
    k, k_ref, key = _cache_key(model, cutoff_hz)
    folder = cache_dir() / f"basis-{key}"
    meta_path = folder / "meta.json"
    if use_cache and meta_path.is_file():
        meta = json.loads(meta_path.read_text())
        try:
            meta_path.touch()                    # recently used: kept by _prune
        except OSError:
            pass
        arrays = {name: np.load(folder / f"{name}.npy", mmap_mode="r" if name == "w_nodes" else None)
                  for name in ARRAYS}
        b = ModalBasis(cutoff_hz=float(meta["cutoff_hz"]), key=key, **arrays)
        scale = k_ref / float(meta["k_ref"])
        return b.scaled(scale) if scale != 1.0 else b
    check_size(model, cutoff_hz)
    b = compute_basis(model, cutoff_hz, k=k, progress=progress)
    b.key = key
    if use_cache:
        _prune(cache_dir())
        for name in ARRAYS:
            with atomic_file(folder / f"{name}.npy") as fh:
                np.save(fh, getattr(b, name))
        with atomic_file(meta_path, "w") as fh:   # last: its presence marks a complete entry
            json.dump(dict(format=FORMAT_VERSION, k_ref=k_ref, cutoff_hz=b.cutoff_hz, modes=b.modes,
                           nbytes=b.nbytes), fh)
    return b
