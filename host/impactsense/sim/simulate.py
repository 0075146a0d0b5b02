"""Simulated drops: the ball, the plate and the four discs, to raw ADC counts like the rig records.

Two solvers (`solver=` or SimParams.solver): "direct", the explicit finite-element model (the reference, below),
and "modal", the same model's modes (`modal.py`, `modal_basis.py`: computed once per plate, cached on disk).

The direct solver has two paths behind one API (`SimParams.method`; "auto" picks direct for up to 4 drops unless the reciprocal
fields are already cached, fast otherwise):
- "direct": one explicit run per drop with the ball, the plate and the discs stepped together for the whole
  record window.
- "fast" (default, for data sets): the plate is linear, so the disc voltage is V_s(t) = (g_s(x, .) * F)(t)
  with g_s(x, t) the voltage of disc s for a force at x. By reciprocity (K, M and the mass-proportional
  damping are symmetric) g_s(x, t) is the plate displacement at x when disc s's sensing functional is
  applied as a load: ONE run per disc gives g_s at every node. The force F(t) needs the local plate response,
  so each drop still runs the ball on the plate, but only for the contact window (until the ball has been away
  for 100 us and half as long as the contact lasted, <= contact_window_ms), then
  V = sum_q F(q dT) g_s(x, t - (q - 1) dT) with F expanded in hat functions on the ADC grid dT (the reciprocal run is driven by that hat). This is
  exact for the discrete model up to the piecewise-linear expansion of F; a touch after the window is lost.
Both paths sample the voltage with hat weights on the ADC grid (a linear-B-spline average, a 1.5 %
attenuation at 20 kHz for 100 kHz sampling).
"""

from __future__ import annotations

import math
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..errors import ConfigError, ImpactSenseError
from . import executor
from .loss import apply_loss_factor
from .model import Model, build_model, impact_velocity
from .params import SimParams


class SimulationError(ImpactSenseError, RuntimeError):
    """The explicit integration failed (NaN/Inf blow-up); the message names the step."""


_CACHE_LOCK = threading.Lock()
_CACHE: dict = {}


def _rig_key(rig) -> tuple:
    return (rig.plate_x_mm, rig.plate_y_mm, rig.sensor_diameter_mm, tuple(map(tuple, rig.sensor_xy_mm.tolist())),
            rig.ball_diameter_mm, rig.ball_mass_g, rig.fs_hz, rig.samples)


def get_model(params: SimParams, rig) -> Model:
    """The model for (params, rig), cached (one entry: the latest) with its reciprocal fields."""
    key = (params, _rig_key(rig))
    with _CACHE_LOCK:
        if key in _CACHE:
            return _CACHE[key]
    model = build_model(params, rig)
    with _CACHE_LOCK:
        _CACHE.clear()
        _CACHE[key] = model
    return model


def clear_cache() -> None:
    """Drops the cached model and its reciprocal fields (about 4 x 600 x nodes float32: ~230 MB by default)."""
    with _CACHE_LOCK:
        _CACHE.clear()


def _run(model: Model, **kw) -> dict:
    try:
        return model.plate.run(**kw)
    except RuntimeError as exc:
        raise SimulationError(str(exc)) from None
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


def check_impacts(rig, params: SimParams, x_mm, y_mm, height_mm):
    """Validated float arrays; ConfigError for impacts off the plate, on a disc, or non-positive heights."""
    x = np.atleast_1d(np.asarray(x_mm, float))
    y = np.atleast_1d(np.asarray(y_mm, float))
    h = np.atleast_1d(np.asarray(height_mm, float))
    n = max(x.size, y.size, h.size)
    try:
        x, y, h = (np.broadcast_to(a, (n,)).copy() for a in (x, y, h))
    except ValueError:
        raise ConfigError(f"x_mm, y_mm, height_mm have incompatible sizes {x.size}, {y.size}, {h.size}") from None
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y)) and np.all(np.isfinite(h))):
        raise ConfigError("impact positions and heights must be finite")
    r_ball = rig.ball_diameter_mm / 2
    for k in range(n):
        if not (0 < x[k] < rig.plate_x_mm and 0 < y[k] < rig.plate_y_mm):
            raise ConfigError(f"impact {k} at ({x[k]:g}, {y[k]:g}) mm lies off the "
                              f"{rig.plate_x_mm:g} x {rig.plate_y_mm:g} mm plate")
        d = np.hypot(rig.sensor_x_mm - x[k], rig.sensor_y_mm - y[k])
        s = int(np.argmin(d))
        if d[s] < rig.sensor_diameter_mm / 2 + r_ball:
            raise ConfigError(f"impact {k} at ({x[k]:g}, {y[k]:g}) mm lands on sensor {rig.sensors[s].name} "
                              f"({d[s]:.1f} mm from its centre; disc radius {rig.sensor_diameter_mm / 2:g} mm)")
        if h[k] <= 0:
            raise ConfigError(f"impact {k}: height_mm must be > 0, got {h[k]:g}")
    return x, y, h


def direct_drop(model: Model, x_m: float, y_m: float, v0: float, *, n_record=None, record_energy=False,
                nan_check_every=50) -> dict:
    """Ball, plate and discs stepped together; volts [4, n_record] on the ADC grid from the first touch."""
    n_rec = model.n_record if n_record is None else n_record
    p = model.params
    out = _run(model, dt_s=model.dt_s, n_steps=n_rec * model.record_every, record_every=model.record_every,
               n_record=n_rec, ball=[x_m, y_m, model.ball_mass_kg, model.k_hertz, v0, p.g_m_s2],
               sensors=model.sensors, record_energy=record_energy, nan_check_every=nan_check_every)
    out["volts"] = np.asarray(out["sensors"])
    return out


# The fast path's contact window ends once the ball has been off the plate (and rising) for QUIET_AFTER_CONTACT_S
# and QUIET_AFTER_CONTACT_FRACTION of the contact's own duration, whichever is longer: a touch after that is lost.
# The second touches seen come well inside that wait (docs/findings.md, "The cold chain's CPU cut", coldchain4);
# the late part of a window steps the whole plate, so a longer wait is the window's dearest part.
QUIET_AFTER_CONTACT_S = 100e-6
QUIET_AFTER_CONTACT_FRACTION = 0.5


def contact_window(model: Model, x_m: float, y_m: float, v0: float) -> dict:
    """The ball on the plate until it has clearly left (fast path): force history per step (force_only: once
    the ball has left, the nodes too far to reach the contact point before the window's end are not stepped;
    the final plate state is not returned, NaN)."""
    p = model.params
    n_steps = int(math.ceil(p.contact_window_ms * 1e-3 / model.dt_s))
    return _run(model, dt_s=model.dt_s, n_steps=n_steps, record_every=model.record_every, n_record=0,
                ball=[x_m, y_m, model.ball_mass_kg, model.k_hertz, v0, p.g_m_s2], stop_after_contact=True,
                quiet_after_contact_s=QUIET_AFTER_CONTACT_S,
                quiet_after_contact_fraction=QUIET_AFTER_CONTACT_FRACTION, force_only=True)


def reciprocal_fields(model: Model, *, workers: int = 2) -> list:
    """g_s at every node: [n_record, nodes] float32 per disc (cached on the model)."""
    fields = getattr(model, "_fields", None)
    if fields is not None:
        return fields

    def one(s):
        out = _run(model, dt_s=model.dt_s, n_steps=model.n_record * model.record_every,
                   record_every=model.record_every, n_record=model.n_record, load=model.sensors[s],
                   record_field=True)
        return np.asarray(out["field"])

    with ThreadPoolExecutor(max_workers=max(1, workers)) as ex:
        fields = list(ex.map(one, range(len(model.sensors))))
    model._fields = fields
    return fields


def delayed_fields(model: Model, delays_s, *, workers: int = 2) -> list:
    """The reciprocal fields with disc s's response delayed by delays_s[s] (s): a channel's time skew acting on
    the analogue signal before the recorder samples it, as a multiplexed ADC or a cable's delay does
    (`analogue_fields`)."""
    return analogue_fields(model, delays_s, None, workers=workers)


def analogue_fields(model: Model, delays_s=None, bonds=None, *, workers: int = 2) -> list:
    """The reciprocal fields with disc s's analogue signal delayed by delays_s[s] (s) and passed through
    bonds[s] (a `bond.DiscBond`: its first-order low-pass in continuous time, then its gain; None: rigid) before
    the recorder samples it. The fraction of a sample and the low-pass act on the reciprocity run's hat load
    (one more solve per such disc: `load_delay_s`, `load_lowpass_s`), the whole samples shift the record; a disc
    with neither keeps the cached field."""
    fields = list(reciprocal_fields(model, workers=workers))
    n = len(fields)
    delays_s = [0.0] * n if delays_s is None else list(delays_s)
    bonds = [None] * n if bonds is None else list(bonds)
    if len(delays_s) != n or len(bonds) != n:
        raise ConfigError(f"disc delays and bonds need one entry per disc ({n})")
    delta = model.record_every * model.dt_s
    for s, (d, bond) in enumerate(zip(delays_s, bonds)):
        tau = 0.0 if bond is None else bond.time_constant_s
        if not d and bond is None:
            continue
        whole = int(math.floor(d / delta + 1e-9))       # a whole number of samples within rounding: no solve
        frac = d - whole * delta
        f = fields[s]
        if frac > 1e-9 * delta or tau > 0:
            f = np.asarray(_run(model, dt_s=model.dt_s, n_steps=model.n_record * model.record_every,
                                record_every=model.record_every, n_record=model.n_record, load=model.sensors[s],
                                record_field=True, load_delay_s=max(frac, 0.0), load_lowpass_s=tau)["field"])
        out = np.zeros_like(f)
        if whole >= 0:
            out[whole:] = f[:f.shape[0] - whole]
        else:
            out[:whole] = f[-whole:]
        if bond is not None:
            out *= np.float32(bond.gain)
        fields[s] = out
    return fields


def fast_drop(model: Model, x_m: float, y_m: float, v0: float, fields: list) -> dict:
    win = contact_window(model, x_m, y_m, v0)
    force = np.asarray(win["force_n"])
    m = model.record_every
    a = force[::m]                                    # F at the ADC grid, a[0] = F(0) = 0
    nodes, wts = model.bilinear(x_m, y_m)
    n_rec = model.n_record
    volts = np.zeros((len(fields), n_rec))
    for s, fld in enumerate(fields):
        g = fld[:, nodes].astype(float) @ wts          # response at x to the hat phi_1
        volts[s] = np.convolve(a[1:], g)[:n_rec]
    win["volts"] = volts
    return win


def _taper(model: Model, volts: np.ndarray) -> np.ndarray:
    n_t = int(round(model.params.taper_ms * 1e-3 * model.fs_hz))
    if n_t > 0:
        ramp = 0.5 * (1 + np.cos(np.pi * (np.arange(n_t) + 1) / n_t))
        volts = volts.copy()
        volts[..., -n_t:] *= ramp
    return volts


MODAL_BATCH = 512   # drops per modal batch (its working memory is ~ batch x (modes + contact steps) x 8 bytes x 8)


def modal_basis(model: Model, *, progress: bool = False):
    """The model's modal basis (modal_basis.load_or_compute, disk-cached), kept on the model."""
    basis = getattr(model, "_basis", None)
    if basis is None:
        from .modal_basis import load_or_compute

        report = None
        if progress:
            import sys

            def report(lam):
                print(f"  modal basis: modes found up to {math.sqrt(max(lam, 0.0)) / (2 * math.pi):.0f} Hz",
                      file=sys.stderr, flush=True)
        basis = load_or_compute(model, progress=report)
        model._basis = basis
    return basis


def _modal_voltages(model: Model, x, y, v0, progress: bool) -> list:
    from .modal import modal_drops

    basis = modal_basis(model, progress=progress)
    results = []
    bar = None
    if progress:
        from ..progress import progress_bar
        bar = progress_bar(total=x.size, desc="simulate (modal)", unit="drop")
    for k in range(0, x.size, MODAL_BATCH):
        sl = slice(k, k + MODAL_BATCH)
        r = modal_drops(model, basis, x[sl] * 1e-3, y[sl] * 1e-3, v0[sl])
        for b in range(r["volts"].shape[0]):
            results.append(dict(volts=r["volts"][b], contacts=int(r["contacts"][b]), force_n=r["force_n"][b],
                                contact_start_s=float(r["contact_start_s"][b]),
                                contact_end_s=float(r["contact_end_s"][b])))
        if bar is not None:
            bar.update(r["volts"].shape[0])
    if bar is not None:
        bar.close()
    return results


def batch_solver(params: SimParams, rig, solver: str | None, x_mm, y_mm, height_mm) -> str:
    """The solver of a batch command's drops at (x_mm, y_mm) from height_mm: `solver` if given ("direct" /
    "modal"; None: params.solver); "auto" (the batch commands' default): the cheaper one for these drops by
    `solver_cost.batch_choice` (the modal basis counted unless it is already cached, the direct path's contact
    windows measured on a few of the drops: both solvers meet the accuracy targets against each other,
    docs/findings.md)."""
    if solver != "auto":
        return solver or params.solver
    from .modal_basis import is_cached
    from .solver_cost import batch_choice

    model = get_model(params, rig)
    return batch_choice(model, x_mm, y_mm, height_mm, cached=is_cached(model))


def simulate_voltages(params: SimParams, rig, x_mm, y_mm, height_mm, *, method: str | None = None,
                      solver: str | None = None, workers: int = 2, progress: bool = False,
                      scheduler: str | None = None, disc_delays_s=None, disc_bonds=None) -> dict:
    """Disc voltages [n, 4, n_record] (volts, ADC grid, t = 0 at the first touch) and contact details.
    solver: "direct" (the explicit FEM; `method` picks its path) or "modal" (None: params.solver).
    scheduler: a Dask scheduler's address (None: executor.scheduler(), the process's; "" : here).
    disc_delays_s: a time skew per disc on the analogue signal; disc_bonds: a `bond.DiscBond` (or None) per disc,
    its strain transfer on the analogue signal (`analogue_fields`; both the direct solver's fast path only)."""
    x, y, h = check_impacts(rig, params, x_mm, y_mm, height_mm)
    solver = solver or params.solver
    if solver not in ("direct", "modal"):
        raise ConfigError(f"solver must be 'direct' or 'modal', got {solver!r}")
    method = method or params.method
    if method not in ("auto", "fast", "direct"):
        raise ConfigError(f"method must be 'auto', 'fast' or 'direct', got {method!r}")
    analogue = disc_delays_s is not None or disc_bonds is not None
    if analogue and (solver != "direct" or method != "fast"):
        raise ConfigError("disc_delays_s and disc_bonds need the direct solver's fast path (method 'fast')")
    address = executor.scheduler() if scheduler is None else scheduler
    if address and not analogue:
        return _on_cluster(address, params, rig, x, y, h, method, solver, progress)
    model = get_model(params, rig)
    v0 = impact_velocity(params, h)
    if solver == "modal":
        return _collect(model, _modal_voltages(model, x, y, v0, progress))
    if method == "auto":  # the fast path costs one full solve per disc up front
        cached = getattr(_CACHE.get((params, _rig_key(rig))), "_fields", None) is not None
        method = "fast" if (x.size > 4 or cached) else "direct"
    fields = reciprocal_fields(model, workers=workers) if method == "fast" else None
    if analogue:
        fields = analogue_fields(model, disc_delays_s, disc_bonds, workers=workers)

    def one(k):
        if method == "fast":
            r = fast_drop(model, x[k] * 1e-3, y[k] * 1e-3, float(v0[k]), fields)
        else:
            r = direct_drop(model, x[k] * 1e-3, y[k] * 1e-3, float(v0[k]))
        keep = ("volts", "contacts", "force_n", "contact_start_s", "contact_end_s")
        return {key: r[key] for key in keep}   # not the final plate state (3 x nodes per drop)

    bar = None
    if progress:
        from ..progress import progress_bar
        bar = progress_bar(total=x.size, desc=f"simulate ({method})", unit="drop")
    results = []
    for r in executor.Executor("", workers=workers).map(one, range(x.size)):
        results.append(r)
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()
    return _collect(model, results, direct=True)


def _simulate_chunk(task) -> dict:
    """A cluster worker's share of a batch: simulate_voltages here, without the (unpicklable) model."""
    params, rig, x, y, h, method, solver = task
    res = simulate_voltages(params, rig, x, y, h, method=method, solver=solver, workers=1, scheduler="")
    return {key: res[key] for key in ("volts", "contacts", "force_n", "contact_s")}


def _on_cluster(address: str, params, rig, x, y, h, method, solver, progress) -> dict:
    """simulate_voltages on a Dask cluster: the drops in chunks, ~2 per worker thread (modal: at most
    MODAL_BATCH). A modal basis is loaded or computed here first, so workers sharing this machine's cache
    (IMPACTSENSE_MODAL_CACHE) load it instead of solving it again."""
    model = get_model(params, rig)
    if solver == "modal":
        modal_basis(model, progress=progress)
    pool = executor.Executor(address)
    n_chunks = max(1, min(x.size, 2 * pool.parallelism()))
    size = int(math.ceil(x.size / n_chunks))
    if solver == "modal":
        size = min(size, MODAL_BATCH)
    if method == "auto":      # each worker pays the fast path's 4 solves once: only for big chunks
        method = "fast" if size > 4 else "direct"
    tasks = [(params, rig, x[k:k + size], y[k:k + size], h[k:k + size], method, solver)
             for k in range(0, x.size, size)]
    bar = None
    if progress:
        from ..progress import progress_bar
        bar = progress_bar(total=x.size, desc=f"simulate ({solver}, cluster)", unit="drop")
    parts = []
    for part in pool.map(_simulate_chunk, tasks):
        parts.append(part)
        if bar is not None:
            bar.update(part["volts"].shape[0])
    if bar is not None:
        bar.close()
    return dict(volts=np.concatenate([p["volts"] for p in parts]), model=model,
                contacts=np.concatenate([p["contacts"] for p in parts]),
                force_n=[f for p in parts for f in p["force_n"]], dt_s=model.dt_s,
                contact_s=np.concatenate([p["contact_s"] for p in parts]))


def _collect(model: Model, results: list, direct: bool = False) -> dict:
    """The drops' records, tapered; direct: the explicit FEM's, given the loss factor the modal solver's poles
    carry (`loss.apply_loss_factor`)."""
    eta = float(model.params.loss_factor) if direct else 0.0
    volts = np.stack([_taper(model, apply_loss_factor(r["volts"], model.fs_hz, eta)) for r in results])
    return dict(volts=volts, model=model, contacts=np.array([r["contacts"] for r in results]),
                force_n=[np.asarray(r["force_n"]) for r in results], dt_s=model.dt_s,
                contact_s=np.array([r["contact_end_s"] - r["contact_start_s"] for r in results]))


INT16_MAX_COUNTS = 32767   # the core's samples (int16): the twin's unclipped counts end there


def to_adc(volts: np.ndarray, params: SimParams, rig, *, noise: bool = False, seed=None,
           clip: bool = True) -> np.ndarray:
    """Volts [n, 4, n_sim] from the first touch -> uint16 counts [n, 4, rig.samples] (bias, pre-trigger).
    clip=False: int16 counts past the ADC's rails (the whole signal, e.g. for the twin's site map), as the core
    takes them (less signal.core_offset: 0 up to 15 bits)."""
    n, c, n_sim = volts.shape
    rec = np.zeros((n, c, rig.samples))
    start = params.pretrigger_samples
    if start >= rig.samples:
        raise ConfigError(f"pretrigger_samples {start} >= record length {rig.samples}")
    take = min(n_sim, rig.samples - start)
    rec[:, :, start:start + take] = volts[:, :, :take]
    counts = rig.bias_counts + params.circuit_gain * rec * (2 ** rig.adc_bits) / rig.vref
    if noise:
        rng = np.random.default_rng(seed)
        counts = counts + rng.normal(0.0, params.noise_counts_rms, counts.shape)
    if not clip:   # the core's int16 counts: less a 16-bit logger's re-centring (signal.core_offset)
        from ..signal import core_offset

        off = core_offset(rig.adc_max)
        counts = counts - off
        if off:   # a 16-bit logger: the int16 range is its own rails (a drop by a sensor clips there, as measured)
            return np.clip(np.rint(counts), -32768, 32767).astype(np.int16)
        if counts.size and np.abs(counts).max() > 32000:
            # a drop next to a sensor may pass even int16 (a thin plate, a heavy ball): it clips there, as a
            # measured one clips at the rails. A typical drop (the median channel peak) past the logger's rails is
            # what a hot front end records (the lab's gain set on low drops: most drops clip, docs/findings.md
            # "Session 27: newuser8"), and the map holds it whole; only a typical drop past the int16 range itself
            # (the map's counts) says the twin's gain does not fit the logger
            typical = float(np.median(np.abs(counts - rig.bias_counts).max(axis=-1)))
            if rig.bias_counts + typical > INT16_MAX_COUNTS:
                raise ConfigError(f"circuit_gain {params.circuit_gain:.4g}: a typical simulated drop peaks at "
                                  f"{typical:.0f} counts from the bias, past the int16 range the twin's counts "
                                  f"hold ({rig.adc_bits}-bit logger, rails 0..{rig.adc_max}): the twin's gain "
                                  "does not fit this logger (calibrate again)")
        return np.clip(np.rint(counts), -32768, 32767).astype(np.int16)
    return np.clip(np.rint(counts), 0, rig.adc_max).astype(np.uint16)


def simulate_drops(params: SimParams, rig, x_mm, y_mm, height_mm, *, noise: bool = False, seed=None,
                   workers: int = 2, progress: bool = True, solver: str | None = None) -> np.ndarray:
    """Raw ADC records uint16 [n, 4, rig.samples] of drops at (x_mm, y_mm) from height_mm, like the rig's.
    solver: "direct" or "modal" (None: params.solver)."""
    res = simulate_voltages(params, rig, x_mm, y_mm, height_mm, workers=workers, progress=progress, solver=solver)
    return to_adc(res["volts"], params, rig, noise=noise, seed=seed)
