"""Sub-problem 1: plate E and nu from the four drops' DToA (Eq. 16), full factorial grid.

Each grid point's ToAs come from the fast first-arrival model (`arrival`): the unit-gain synthetic signal of
every drop and sensor is scaled so its peak equals the measured peak of that channel (the picker then sees the
same threshold-to-peak ratio as on the measured drop), quantised, and picked by the signal core. The loss is
Eq. 16: sum over drops and the six sensor pairs of (DToA measured - DToA simulated)^2 [us^2].
"""

from __future__ import annotations

import os

import numpy as np

from .. import _core
from ..signal import config_dict, core_config, core_samples
from ..outputs import atomic_file
from ..progress import progress_bar
from ..sim.executor import Executor
from . import arrival

PAIR_I = np.array(_core.PAIR_I)
PAIR_J = np.array(_core.PAIR_J)

# the grid search (`search_grid`): a grid of more points than this is searched coarse to fine (a wide prior's
# full grid at the default steps is ~300,000 points, ~120x a known material's); the first level steps E by
# COARSE_E_REL (relative) and nu by COARSE_NU_STEP, each later level refines the best point's box by REFINE_FACTOR
FULL_GRID_MAX_POINTS = 5000
COARSE_E_REL = 0.04
COARSE_NU_STEP = 0.03
REFINE_FACTOR = 4


def grid_axes(e_min_mpa=1500.0, e_max_mpa=65000.0, e_step_mpa=250.0, nu_min=0.30, nu_max=0.40,
              nu_step=0.001):
    e = np.arange(e_min_mpa, e_max_mpa + 0.5 * e_step_mpa, e_step_mpa)
    nu = np.round(np.arange(nu_min, nu_max + 0.5 * nu_step, nu_step), 6)
    return e, nu


def delay_misfit(dtoa_sim_us: np.ndarray, dtoa_meas_us: np.ndarray) -> np.ndarray:
    """Eq. 16 over drops and pairs; dtoa_sim [..., D, 6], dtoa_meas [D, 6]. A missing pick costs (1 ms)^2."""
    err = dtoa_sim_us - dtoa_meas_us
    err = np.where(np.isfinite(err), err, 1000.0)
    return np.sum(err ** 2, axis=(-1, -2))


def fast_loss(setup, cfg_state, peak, dtoa_meas, e_mpa, nu, noise_counts=0.0, n_noise=1, seed=0):
    """Eq. 16 of the fast model for plates (e_mpa[i], nu[i]); returns loss [P] and dtoa [P, D, 6].

    The rig's noise (`noise_counts` rms) is added before picking, `n_noise` seeded realisations (the same for
    every plate: common random numbers keep the loss surface smooth) and the ToAs averaged: the AIC onset of
    a noiseless record is not the onset the picker finds in a real one."""
    unit = arrival.synth_unit(setup, np.asarray(e_mpa) * 1e6, np.asarray(nu))
    return picked_loss(unit, cfg_state, peak, dtoa_meas, noise_counts, n_noise, seed)


def picked_loss(unit, cfg_state, peak, dtoa_meas, noise_counts=0.0, n_noise=1, seed=0):
    """Eq. 16 of unit-gain synthetic signals [P, D, 4, S] scaled to the measured peaks, the rig's noise added,
    quantised and picked by the signal core (`fast_loss`); returns loss [P] and dtoa [P, D, 6]."""
    cfg = core_config(**{k: v for k, v in cfg_state.items() if k != "bias"})
    peak_unit = np.abs(unit).max(axis=-1)
    gain = peak[None] / np.where(peak_unit > 0, peak_unit, 1.0)
    clean = unit * gain[..., None] + cfg_state.get("bias", 2048)
    rng = np.random.default_rng(seed)
    toas = []
    for _ in range(max(1, n_noise)):
        noisy = clean + rng.normal(0.0, noise_counts, clean.shape[1:])[None] if noise_counts > 0 else clean
        adc = core_samples(noisy.reshape(-1, 4, unit.shape[-1]), cfg)
        out = _core.extract_batch(adc, cfg)
        toas.append(out["toa_us"].reshape(unit.shape[:-1]).astype(float))
    toa = np.mean(toas, axis=0)
    dtoa = toa[..., PAIR_I] - toa[..., PAIR_J]
    return delay_misfit(dtoa, dtoa_meas), dtoa


def cfg_state(cfg, bias):
    """The core's configuration and the ADC bias as a picklable dict (for the worker processes)."""
    return {**config_dict(cfg), "bias": bias}


def _chunk_task(args):
    return fast_loss(*args)[0]


def run_grid(setup, cfg, bias, peak, dtoa_meas, e_axis, nu_axis, *, cache_path=None, workers=2,
             chunk=48, progress=True, noise_counts=0.0, n_noise=1, seed=0, mask=None):
    """Loss over the grid [len(e_axis), len(nu_axis)] (only the points where `mask` is True; the others NaN
    unless an earlier call filled them); resumable from `cache_path` (npz)."""
    ee, nn = np.meshgrid(e_axis, nu_axis, indexing="ij")
    wanted = np.ones(ee.size, bool) if mask is None else np.asarray(mask, bool).ravel()
    e_flat, nu_flat = ee.ravel(), nn.ravel()
    loss = np.full(e_flat.size, np.nan)
    if cache_path and os.path.exists(cache_path):
        with np.load(cache_path) as z:
            if (z["e_axis"].shape == e_axis.shape and np.allclose(z["e_axis"], e_axis)
                    and z["nu_axis"].shape == nu_axis.shape and np.allclose(z["nu_axis"], nu_axis)
                    and np.allclose(z["dtoa_meas"], dtoa_meas)
                    and float(z["noise"]) == float(noise_counts) * 1000 + n_noise):
                loss = z["loss"].ravel().copy()
    pending = np.flatnonzero(wanted & np.isnan(loss))
    todo = [pending[i:i + chunk] for i in range(0, pending.size, chunk)]
    state = cfg_state(cfg, bias)

    def save():
        if cache_path:
            with atomic_file(cache_path) as fh:
                np.savez(fh, loss=loss.reshape(ee.shape), e_axis=e_axis, nu_axis=nu_axis, dtoa_meas=dtoa_meas,
                         noise=float(noise_counts) * 1000 + n_noise)

    bar = progress_bar(progress, total=len(todo), desc="plate grid (E, nu)", unit="chunk")
    tasks = [(setup, state, peak, dtoa_meas, e_flat[idx], nu_flat[idx], noise_counts, n_noise, seed)
             for idx in todo]
    for k, (idx, res) in enumerate(zip(todo, Executor(workers=workers, kind="processes").map(_chunk_task, tasks))):
        loss[idx] = res
        bar.update(1)
        if k % 50 == 49:
            save()
    bar.close()
    save()
    return loss.reshape(ee.shape)


def _coarse_indices(n, stride):
    """Every `stride`-th index of 0..n-1 and the last one."""
    return np.union1d(np.arange(0, n, max(1, stride)), [n - 1])


def coarse_plan(e_axis, nu_axis):
    """The first level of the coarse-to-fine search: E indices at relative steps of COARSE_E_REL (the lattice
    points nearest a geometric sequence: a wide prior spans two decades of E) and nu indices every
    COARSE_NU_STEP. Returns the index arrays (sorted, unique)."""
    e0, step = float(e_axis[0]), float(e_axis[1] - e_axis[0]) if e_axis.size > 1 else 1.0
    n_geo = int(np.ceil(np.log(e_axis[-1] / e_axis[0]) / np.log1p(COARSE_E_REL))) + 1
    geo = np.geomspace(e_axis[0], e_axis[-1], max(2, n_geo))
    e_idx = np.unique(np.clip(np.rint((geo - e0) / step).astype(int), 0, e_axis.size - 1))
    nu_step = float(nu_axis[1] - nu_axis[0]) if nu_axis.size > 1 else 1.0
    nu_idx = _coarse_indices(nu_axis.size, int(np.ceil(COARSE_NU_STEP / nu_step - 1e-9)))
    return e_idx, nu_idx


def _gap(idx, i):
    """The largest index gap of the sorted level `idx` next to its member i (how far the minimum can be)."""
    k = int(np.searchsorted(idx, i))
    lo = idx[k] - idx[k - 1] if k > 0 else 0
    hi = idx[k + 1] - idx[k] if k + 1 < idx.size else 0
    return max(1, int(lo), int(hi))


def search_grid(evaluate, e_axis, nu_axis):
    """A loss over the grid [len(e_axis), len(nu_axis)] (`evaluate(mask)`: the loss with at least the points
    where mask is True filled, e.g. `run_grid`'s, resumable): every point when the grid has at most
    FULL_GRID_MAX_POINTS; else coarse to fine (docs/method.md): the `coarse_plan` lattice, then boxes of
    +-(gap + stride) around the best point so far at strides of a quarter of the previous level's gap, down
    to the grid's own steps. Points not evaluated read NaN."""
    n_e, n_nu = e_axis.size, nu_axis.size
    if n_e * n_nu <= FULL_GRID_MAX_POINTS:
        return evaluate(np.ones((n_e, n_nu), bool))
    e_idx, nu_idx = coarse_plan(e_axis, nu_axis)
    mask = np.zeros((n_e, n_nu), bool)
    mask[np.ix_(e_idx, nu_idx)] = True
    loss = evaluate(mask)
    i, j = np.unravel_index(np.nanargmin(loss), loss.shape)
    ge, gn = _gap(e_idx, i), _gap(nu_idx, j)
    while True:
        se, sn = max(1, ge // REFINE_FACTOR), max(1, gn // REFINE_FACTOR)
        e_box = np.arange(max(0, i - ge - se), min(n_e, i + ge + se + 1), se)
        nu_box = np.arange(max(0, j - gn - sn), min(n_nu, j + gn + sn + 1), sn)
        mask = np.zeros((n_e, n_nu), bool)
        mask[np.ix_(e_box, nu_box)] = True
        loss = evaluate(mask)
        i, j = np.unravel_index(np.nanargmin(loss), loss.shape)
        if se == 1 and sn == 1:
            return loss
        ge, gn = se, sn


def refine_minimum(loss, e_axis, nu_axis):
    """Grid minimum (the method picks the grid point; no interpolation)."""
    i, j = np.unravel_index(np.nanargmin(loss), loss.shape)
    return float(e_axis[i]), float(nu_axis[j]), float(loss[i, j])


def near_optimal_ranges(loss, e_axis, nu_axis, factor=1.25):
    """E and nu intervals whose best loss stays within `factor` x the minimum (how well each is pinned)."""
    lmin = np.nanmin(loss)
    ok = np.where(np.isfinite(loss), loss, np.inf) <= factor * lmin      # points not evaluated (NaN): not ok
    e_ok = e_axis[ok.any(axis=1)]
    nu_ok = nu_axis[ok.any(axis=0)]
    return {"factor": factor, "E_mpa": [float(e_ok.min()), float(e_ok.max())],
            "nu": [float(nu_ok.min()), float(nu_ok.max())]}


def contour_plot(loss, e_axis, nu_axis, best, path, title="Eq. 16 loss over the plate grid"):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    z = np.log10(np.maximum(loss.T, 1e-9))
    zoom = (e_axis >= 0.6 * best[0]) & (e_axis <= 1.6 * best[0])
    ee, nn = np.meshgrid(e_axis, nu_axis)
    for ax, sel, label in ((axes[0], slice(None), "full grid"), (axes[1], zoom, "around the minimum")):
        if np.count_nonzero(np.ones_like(e_axis, bool)[sel]) < 2:
            sel = slice(None)
        done = np.isfinite(z[:, sel])
        if done.all():
            cs = ax.contourf(e_axis[sel], nu_axis, z[:, sel], levels=30, cmap="viridis")
        else:                                # a coarse-to-fine search: the points it evaluated
            cs = ax.tricontourf(ee[:, sel][done], nn[:, sel][done], z[:, sel][done], levels=30, cmap="viridis")
        fig.colorbar(cs, ax=ax, label="log10 loss [us^2]")
        ax.plot(best[0], best[1], "r*", ms=12, label=f"min E={best[0]:.0f} MPa, nu={best[1]:.3f}")
        ax.set_xlabel("E [MPa]")
        ax.set_ylabel("nu [-]")
        ax.set_title(f"{title}: {label}", fontsize=9)
        ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
