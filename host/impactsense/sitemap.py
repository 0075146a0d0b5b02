"""The twin's site map: the simulated per-channel energies of a drop from one height at every grid point.

A sensor's arrival energy depends on where the plate was hit at a scale of a few millimetres (the direct
wave meets its reflections from the nearest edges; docs/findings.md, "Energy class"). The calibrated twin
reproduces that pattern, so the map holds, for a regular grid over the plate, the 16 features the core's
twin_features() computes (twin.h: log10 energies of 4 channels x arrival, Delta^1..3) of a simulated drop
from `ref_height_mm`, quantised to one byte each so the same table fits the board's flash. The host and the
board read the same bytes through the same C++ (impactcore twin_estimate).

    impactsense sitemap --calibration CAL.json --out site-map.npz [--step-mm 5]
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import _core
from .errors import DataError
from .pipeline import featurize
from .signal import SignalConfig

MISSING = int(_core.SITE_MAP_MISSING)
N_FEATURES = int(_core.TWIN_FEATURES)
TWIN_FEATURE_NAMES = [f"log_{kind}_{c}" for c in range(4) for kind in ("arrival", "diff1", "diff2", "diff3")]
FORMAT = "impactsense-site-map/1"


@dataclass
class SiteMap:
    x0_mm: float
    y0_mm: float
    step_mm: float
    nx: int
    ny: int
    base: np.ndarray          # float32 [16]
    scale: np.ndarray         # float32 [16]
    q: np.ndarray             # uint8 [nx * ny, 16]; row i * ny + j; MISSING where no drop (a sensor disc)
    ref_height_mm: float
    source: dict = field(default_factory=dict)   # twin parameters, rig and signal the map was made with

    @property
    def xy_mm(self) -> np.ndarray:
        """Grid point coordinates [nx * ny, 2] in row order."""
        i, j = np.meshgrid(np.arange(self.nx), np.arange(self.ny), indexing="ij")
        return np.stack([self.x0_mm + self.step_mm * i.ravel(), self.y0_mm + self.step_mm * j.ravel()], 1)

    @property
    def present(self) -> np.ndarray:
        return self.q[:, 0] != MISSING

    def values(self) -> np.ndarray:
        """Dequantised features [nx * ny, 16] (float32, the board's arithmetic); NaN at missing points."""
        v = self.base[None, :] + self.scale[None, :] * self.q.astype(np.float32)
        v[~self.present] = np.nan
        return v.astype(np.float32)

    def nearest(self, xy_mm: np.ndarray) -> np.ndarray:
        """Features of the nearest present grid point to each position [n, 2] -> [n, 16]."""
        xy_mm = np.asarray(xy_mm, float).reshape(-1, 2)
        from scipy.spatial import cKDTree

        pts = self.xy_mm[self.present]
        _, k = cKDTree(pts).query(xy_mm)
        return self.values()[self.present][k]

    def fingerprint(self) -> str:
        h = hashlib.sha256()
        for a in (self.base, self.scale, self.q):
            h.update(np.ascontiguousarray(a).tobytes())
        h.update(json.dumps([self.x0_mm, self.y0_mm, self.step_mm, self.nx, self.ny, self.ref_height_mm]).encode())
        return h.hexdigest()[:16]

    # ----- files -----
    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        meta = dict(format=FORMAT, x0_mm=self.x0_mm, y0_mm=self.y0_mm, step_mm=self.step_mm, nx=self.nx,
                    ny=self.ny, ref_height_mm=self.ref_height_mm, feature_names=TWIN_FEATURE_NAMES,
                    source=self.source)
        from .outputs import atomic_file

        with atomic_file(path) as fh:
            np.savez_compressed(fh, base=self.base, scale=self.scale, q=self.q, meta=np.array(json.dumps(meta)))
        return path

    @classmethod
    def load(cls, path: str | Path) -> "SiteMap":
        path = Path(path)
        if not path.is_file():
            raise DataError(path, None, "site map not found (make one with `impactsense sitemap`)")
        try:
            with np.load(path, allow_pickle=False) as z:
                meta = json.loads(str(z["meta"]))
                base, scale, q = z["base"], z["scale"], z["q"]
        except (OSError, ValueError, KeyError) as exc:
            raise DataError(path, None, f"not a site map file ({exc})") from None
        if meta.get("format") != FORMAT:
            raise DataError(path, "format", f"expected {FORMAT}, got {meta.get('format')!r}")
        if meta.get("feature_names") != TWIN_FEATURE_NAMES:
            raise DataError(path, "feature_names", "made for another core's twin features; rebuild it")
        nx, ny = int(meta["nx"]), int(meta["ny"])
        if q.shape != (nx * ny, N_FEATURES) or q.dtype != np.uint8:
            raise DataError(path, "q", f"expected uint8 [{nx * ny}, {N_FEATURES}], got {q.dtype} {q.shape}")
        if base.shape != (N_FEATURES,) or scale.shape != (N_FEATURES,):
            raise DataError(path, "base", f"base and scale need {N_FEATURES} values")
        return cls(x0_mm=float(meta["x0_mm"]), y0_mm=float(meta["y0_mm"]), step_mm=float(meta["step_mm"]),
                   nx=nx, ny=ny, base=base.astype(np.float32), scale=scale.astype(np.float32), q=q,
                   ref_height_mm=float(meta["ref_height_mm"]), source=meta.get("source", {}))


BUNDLED = Path(__file__).parent / "data" / "twin" / "site-map.npz"


def rig_matches(a: dict, b) -> bool:
    """True when a map's recorded sensor positions are the rig's (within 0.5 mm)."""
    sensors = np.asarray(a.get("rig_sensors_mm", []), float)
    return sensors.shape == (4, 2) and bool(np.all(np.abs(sensors - b.sensor_xy_mm) < 0.5))


def resolve_site_map(arg: str | None, rig) -> SiteMap | None:
    """--site-map: a file, 'none', or 'auto' (the bundled twin's map when the rig is the bundled rig's)."""
    if arg is None or arg == "auto":
        if BUNDLED.is_file():
            site = SiteMap.load(BUNDLED)
            if rig_matches(site.source, rig):
                return site
        return None
    if arg == "none":
        return None
    site = SiteMap.load(arg)
    if not rig_matches(site.source, rig):
        raise DataError(arg, "source.rig_sensors_mm", "site map was made for another rig's sensor positions")
    return site


def twin_features(features) -> tuple[np.ndarray, np.ndarray]:
    """The core's 16 twin features [R, 16] and usable-feature masks [R] (uint16) of featurize() output."""
    raw = features.raw
    return _core.twin_features_batch(np.ascontiguousarray(raw["window_energy"], np.float32),
                                     np.ascontiguousarray(raw["diff_energy"], np.float32),
                                     np.ascontiguousarray(features.flags, np.uint8))


def quantise(values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """float [n, 16] (NaN rows = missing) -> base, scale, uint8 q (0..254; 255 = missing)."""
    present = np.isfinite(values).all(1)
    if not present.any():
        raise DataError("site map", None, "no grid point has a usable simulated drop")
    lo = values[present].min(0)
    hi = values[present].max(0)
    scale = np.maximum(hi - lo, 1e-6) / 254.0
    q = np.full(values.shape, MISSING, np.uint8)
    q[present] = np.clip(np.rint((values[present] - lo) / scale), 0, 254).astype(np.uint8)
    return lo.astype(np.float32), scale.astype(np.float32), q


def grid(rig, step_mm: float, margin_mm: float) -> tuple[float, float, int, int]:
    if not (0 < step_mm <= 50):
        raise DataError("site map", "step_mm", f"must be in (0, 50], got {step_mm}")
    nx = int(np.floor((rig.plate_x_mm - 2 * margin_mm) / step_mm + 1e-9)) + 1
    ny = int(np.floor((rig.plate_y_mm - 2 * margin_mm) / step_mm + 1e-9)) + 1
    if nx < 2 or ny < 2:
        raise DataError("site map", "margin_mm", "the plate is too small for this step and margin")
    return margin_mm, margin_mm, nx, ny


def coarse_indices(n: int, every: int) -> np.ndarray:
    """Every `every`-th index of 0..n-1 and the last one (the edges are simulated, never extrapolated)."""
    return np.union1d(np.arange(0, n, every), [n - 1])


def refine(values: np.ndarray) -> np.ndarray:
    """Features [nx, ny, 16] simulated at some grid points (NaN: not simulated) -> every point [nx * ny, 16]:
    piecewise linear on the simulated points' triangulation in the plane of grid indices (scipy griddata), the
    nearest simulated point where none encloses it. Simulated points are kept as they are."""
    from scipy.interpolate import griddata

    nx, ny = values.shape[:2]
    flat = np.asarray(values, float).reshape(nx * ny, -1)
    fi, fj = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    pts = np.stack([fi.ravel(), fj.ravel()], 1).astype(float)
    have = np.isfinite(flat).all(1)
    if have.sum() < 3:
        raise DataError("site map", None, "fewer than three grid points have a usable simulated drop")
    out = flat.copy()
    todo = ~have
    out[todo] = griddata(pts[have], flat[have], pts[todo], method="linear")
    hole = ~np.isfinite(out).all(1)
    if hole.any():
        out[hole] = griddata(pts[have], flat[have], pts[hole], method="nearest")
    return out


def simulated_points(xy_mm: np.ndarray, nx: int, ny: int, every: int, plate_mm: tuple[float, float],
                     edge_band_mm: float) -> np.ndarray:
    """Which grid points [nx * ny] a map simulated every every-th grid line simulates: the lattice
    (`coarse_indices`) and every point within edge_band_mm of a plate edge (where the site factor changes
    within millimetres: the edges' reflections)."""
    keep = np.zeros((nx, ny), bool)
    keep[np.ix_(coarse_indices(nx, every), coarse_indices(ny, every))] = True
    x, y = xy_mm[:, 0], xy_mm[:, 1]
    edge = np.minimum.reduce([x, plate_mm[0] - x, y, plate_mm[1] - y])
    return keep.ravel() | (edge <= edge_band_mm)


def map_solver(params, rig, solver: str | None, n_drops: int, ref_height_mm: float) -> str | None:
    """The solver of a site map of n_drops drops: "auto" is the cheaper by `sim.solver_cost.choose`, the direct
    path priced with its contact window measured on the map's pilot points (as `site_map_cost`)."""
    if solver != "auto":
        return solver
    from .sim.modal_basis import is_cached
    from .sim.simulate import get_model
    from .sim.solver_cost import choose, measured_contact_windows

    model = get_model(params, rig)
    pilot = pilot_points(rig)
    window = measured_contact_windows(model, pilot[:, 0], pilot[:, 1], ref_height_mm)
    return choose(model, int(n_drops), window, cached=is_cached(model))[0]


EDGE_BAND_MM = 40.0   # with every > 1: points this near an edge are all simulated (docs/findings.md, Session 24)
SITE_MAP_CPU_S = 600.0   # the chain's default budget for the map (estimated CPU s; issue 15: the chain <= 10 min on 2 cores)
MAX_EVERY = 4
ORDINAL = {2: "2nd", 3: "3rd"}


def grid_xy(x0: float, y0: float, step_mm: float, nx: int, ny: int) -> np.ndarray:
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    return np.stack([x0 + step_mm * i.ravel(), y0 + step_mm * j.ravel()], 1)


def plan(rig, step_mm: float, margin_mm: float, every: int = 1, edge_band_mm: float = EDGE_BAND_MM):
    """The grid (x0, y0, nx, ny), which points lie on a sensor disc (no drop there) and which are simulated:
    every point off the discs when every is 1, else `simulated_points` off the discs."""
    if not (isinstance(every, (int, np.integer)) and every >= 1):
        raise DataError("site map", "every", f"must be an integer >= 1, got {every!r}")
    x0, y0, nx, ny = grid(rig, step_mm, margin_mm)
    xy = grid_xy(x0, y0, step_mm, nx, ny)
    d = np.hypot(xy[:, None, 0] - rig.sensor_x_mm[None], xy[:, None, 1] - rig.sensor_y_mm[None]).min(1)
    on_disc = d < rig.sensor_diameter_mm / 2 + rig.ball_diameter_mm / 2 + 0.5
    sim = ~on_disc
    if every > 1:
        sim &= simulated_points(xy, nx, ny, every, (rig.plate_x_mm, rig.plate_y_mm), edge_band_mm)
    return (x0, y0, nx, ny), on_disc, sim


def pilot_points(rig, step_mm: float = 5.0, margin_mm: float = 10.0, n: int | None = None) -> np.ndarray:
    """The grid points [n, 2] (mm) whose contact windows price the map (`solver_cost.measured_contact_windows`): n
    of the map's points off the discs, drawn with a fixed seed (the same points for the same rig)."""
    from .sim.solver_cost import PILOT_DROPS, pilot_rows

    (x0, y0, nx, ny), _, sim = plan(rig, step_mm, margin_mm, 1)
    rows = np.flatnonzero(sim)
    return grid_xy(x0, y0, step_mm, nx, ny)[rows[pilot_rows(rows.size, PILOT_DROPS if n is None else n)]]


def site_map_cost(params, rig, step_mm: float = 5.0, margin_mm: float = 10.0, ref_height_mm: float = 175.0,
                  every: int = 1, edge_band_mm: float = EDGE_BAND_MM, *, _model=None) -> dict:
    """What `build_site_map` with solver "auto" will cost: grid points, the drops simulated (`plan`), the
    solver `sim.simulate.batch_solver` takes and its estimated CPU seconds (`sim.solver_cost`; the modal basis
    counted unless cached; the direct path's contact window measured on PILOT_DROPS of the map's points,
    `solver_cost.measured_contact_windows`, not the rigid-Hertz estimate: on a thin plate the ball chatters)."""
    from .sim.modal_basis import is_cached
    from .sim.simulate import get_model
    from .sim.solver_cost import choose, measured_contact_windows

    model, cached = _model or (get_model(params, rig), is_cached(get_model(params, rig)))
    (_, _, nx, ny), _, sim = plan(rig, step_mm, margin_mm, every, edge_band_mm)
    n = int(sim.sum())
    pilot = pilot_points(rig, step_mm, margin_mm)
    window = measured_contact_windows(model, pilot[:, 0], pilot[:, 1], ref_height_mm)
    solver, est = choose(model, n, window, cached=cached)
    return {"nx": nx, "ny": ny, "step_mm": step_mm, "points": nx * ny, "simulated": n, "every": every,
            "edge_band_mm": float(edge_band_mm), "solver": solver, "cpu_s": float(est[f"{solver}_cpu_s"]),
            "window_steps": window["steps"], "window": window}


# the plans a budget steps through, finest first: every K-th line with the 40 mm edge band, then (the coarsest K
# still over) a narrower band; a large thin plate's band alone is ~6,000 points (docs/findings.md, Session 25)
BUDGET_PLANS = ((1, EDGE_BAND_MM), (2, EDGE_BAND_MM), (3, EDGE_BAND_MM), (MAX_EVERY, EDGE_BAND_MM),
                (MAX_EVERY, 20.0), (MAX_EVERY, 10.0), (MAX_EVERY, 0.0))


def every_for_budget(params, rig, cpu_budget_s: float | None, step_mm: float = 5.0, margin_mm: float = 10.0,
                     ref_height_mm: float = 175.0) -> dict:
    """`site_map_cost` of the first of BUDGET_PLANS (every, edge band; every = 1: every grid point) whose
    estimated CPU time is within cpu_budget_s (None or <= 0: no budget, every point), else the last; "fits" says
    whether it is within."""
    from .sim.modal_basis import is_cached
    from .sim.simulate import get_model

    model = get_model(params, rig)
    known = (model, is_cached(model))
    for every, band in BUDGET_PLANS:
        cost = site_map_cost(params, rig, step_mm, margin_mm, ref_height_mm, every, band, _model=known)
        fits = not cpu_budget_s or cpu_budget_s <= 0 or cost["cpu_s"] <= cpu_budget_s
        if fits:
            break
    return {**cost, "fits": bool(fits), "budget_cpu_s": cpu_budget_s}


def describe_cost(cost: dict) -> str:
    """One line for the user: the grid, what is simulated, the solver and its estimated CPU time."""
    line = (f"{cost['points']:,} points ({cost['nx']} x {cost['ny']} at {cost['step_mm']:g} mm), "
            f"{cost['simulated']:,} drops by the {cost['solver']} solver, ~{cost['cpu_s'] / 60:.1f} CPU-min estimated")
    if cost["every"] > 1:
        band = cost.get("edge_band_mm", EDGE_BAND_MM)
        edge = f" and the points within {band:g} mm of an edge" if band > 0 else ""
        line += (f"; over the budget of {cost['budget_cpu_s'] / 60:.0f} CPU-min every point is not simulated: every "
                 f"{ORDINAL.get(cost['every'], str(cost['every']) + 'th')} grid line{edge}, the rest "
                 "interpolated (a coarser map: the twin's position and class lose some accuracy, docs/findings.md "
                 "Session 24 sitemapfast; a larger --site-map-cpu-s, or 0, simulates every point)")
    if not cost.get("fits", True):
        line += " (still over the budget at the coarsest plan)"
    return line


def build_site_map(params, rig, signal: SignalConfig, *, step_mm: float = 5.0, margin_mm: float = 10.0,
                   ref_height_mm: float = 175.0, workers: int = 2, chunk: int = 400,
                   progress: bool = True, capture=None, solver: str | None = None, every: int = 1,
                   edge_band_mm: float = EDGE_BAND_MM) -> SiteMap:
    """Simulate a drop from ref_height_mm at every grid point (off the sensor discs) and keep the core's
    twin features. The counts are not clipped (int16 range, the core's clip detection off), so the map
    holds the whole energy even where the rig's ADC would saturate; the rig's clipped channels are left out
    of the match instead (twin.h).

    capture: how a device other than the lab logger takes the drops, e.g. the board
    (board.capture.board_capture: resampled to 4 x 50 kHz with the SAADC scan delays, cut by the firmware
    app): a callable int16 counts [R, 4, rig.samples] at the rig's rate -> (captures int16 [R', 4, n],
    rows [R'] of the drops captured), keeping the int16 range; `signal` is then that device's. Default: the
    counts as the rig records them. solver: "direct", "modal" (None: params.solver) or "auto" (the cheaper
    for this many drops, `sim.simulate.batch_solver`); the command prints the one used. every > 1: simulate
    only the points `plan` lists (every every-th grid line in x and y, the last ones, the points within
    edge_band_mm of an edge) and fill the others by `refine`; the map's step, its format and the match stay the same (docs/method.md,
    "The site map's cost")."""
    from .sim import simulate_voltages, to_adc

    (x0, y0, nx, ny), on_disc, sim = plan(rig, step_mm, margin_mm, every, edge_band_mm)
    m = SiteMap(x0, y0, step_mm, nx, ny, np.zeros(N_FEATURES, np.float32), np.ones(N_FEATURES, np.float32),
                np.zeros((nx * ny, N_FEATURES), np.uint8), ref_height_mm)
    xy = m.xy_mm
    todo = np.flatnonzero(sim)
    solver = map_solver(params, rig, solver, todo.size, ref_height_mm)
    sig = SignalConfig.from_dict(signal.to_dict())
    sig.adc_min, sig.adc_max, sig.sample_offset = -32768, 32767, 0   # to_adc(clip=False): the core's counts
    values = np.full((nx * ny, N_FEATURES), np.nan)
    bar = None
    if progress:
        from .progress import progress_bar
        bar = progress_bar(total=todo.size, desc="site map", unit="drop")
    def features_of(rows, volts):
        counts = to_adc(volts, params, rig, clip=False)
        got = np.arange(rows.size)
        if capture is not None:
            counts, got = capture(counts)
        f = featurize(counts, sig)
        feats, usable = twin_features(f)
        ok = (usable == (1 << N_FEATURES) - 1) & np.isfinite(feats).all(1)
        values[rows[got[ok]]] = feats[ok]
        if bar is not None:
            bar.update(rows.size)

    # a chunk's features (one thread: the ADC model, the core) are made while the next chunk's drops are
    # simulated, so the cores do not wait for them between chunks; the same map either way
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=1) as post:
        pending = None
        for k in range(0, todo.size, chunk):
            rows = todo[k:k + chunk]
            res = simulate_voltages(params, rig, xy[rows, 0], xy[rows, 1], np.full(rows.size, ref_height_mm),
                                    workers=workers, solver=solver)
            if pending is not None:
                pending.result()
            pending = post.submit(features_of, rows, res["volts"])
        if pending is not None:
            pending.result()
    if bar is not None:
        bar.close()
    if every > 1:
        failed = todo[~np.isfinite(values[todo]).all(1)]   # simulated, no usable drop: left missing
        values = refine(values.reshape(nx, ny, N_FEATURES))
        values[on_disc] = np.nan
        values[failed] = np.nan
    m.base, m.scale, m.q = quantise(values)
    m.source = {"simulated_every": every, "sim_params": params.to_dict() if hasattr(params, "to_dict") else {},
                "rig_sensors_mm": rig.sensor_xy_mm.tolist(), "signal": signal.to_dict()}
    if every > 1:
        m.source["edge_band_mm"] = float(edge_band_mm)
    return m
