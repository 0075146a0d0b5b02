"""`CalibrationProblem`: what every calibration stage reads (the session, its four drops and their targets, the
core's configurations, the twin's simulator, the cache folder) and what the stages build up (the twin's
parameters, CAL.json's blocks).

The twin's parameters (`params`) are `SimParams` fields by name (`fem.base_params`; `SimParams.from_rig(rig,
**params)` is the simulator's parameter set).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from .. import _core
from ..data import load_session
from ..errors import ConfigError
from ..signal import channel_delays_us, core_config, core_samples
from . import drops as drops_mod, fem, plate, plate_fem, priors
from .cache import StageClock, key
from .options import CalibrateOptions


def picker_overrides(opts: CalibrateOptions) -> dict:
    """The calibration's choices for the core's picker (signal.core_config overrides): its AIC blend and, when
    given, the channel delays."""
    out = {"aic_blend": float(opts.aic_blend)}
    if opts.rig_delay_us is not None:
        if len(opts.rig_delay_us) != 4:
            raise ConfigError("--rig-delay-us needs four values (microseconds, channel 0..3)")
        out["rig_delay_us"] = [float(v) for v in opts.rig_delay_us]
    return out


def measured_core_config(rig, opts: CalibrateOptions):
    """The core's configuration for the rig's recordings."""
    return core_config(rig, **picker_overrides(opts))


def sim_core_config(rig, opts: CalibrateOptions):
    """The core's configuration for simulated recordings: the same picker, no channel delays (the simulator
    samples every channel at once)."""
    return core_config(rig, **{**picker_overrides(opts), "rig_delay_us": [0.0, 0.0, 0.0, 0.0]})


def sim_features(adc_u16, cfg_sim, noise_counts=0.0, n_noise=1, seed=0):
    """Core features of simulated records, with the rig's noise added (`n_noise` seeded realisations,
    averaged): the picker must see what it sees on the rig."""
    adc = np.asarray(adc_u16).astype(float)
    rng = np.random.default_rng(seed)
    acc = {}
    for _ in range(max(1, n_noise)):
        x = adc + rng.normal(0.0, noise_counts, adc.shape) if noise_counts > 0 else adc
        out = _core.extract_batch(core_samples(x, cfg_sim), cfg_sim)
        for k in ("toa_us", "energy", "residual_ratio"):
            acc.setdefault(k, []).append(out[k].astype(float))
    toa = np.mean(acc["toa_us"], axis=0)
    return {"toa_us": toa, "dtoa_us": toa[:, plate.PAIR_I] - toa[:, plate.PAIR_J],
            "energy": np.mean(acc["energy"], axis=0), "residual_ratio": np.mean(acc["residual_ratio"], axis=0)}


@dataclass
class DropsAndTwin:
    """What comparing the twin with the chosen drops needs: the session, the drops' targets, the core's features
    of every recording and its configurations, the twin's simulator and the rig noise put on its records."""

    session: object
    targets: drops_mod.DropTargets  # the four drops' measured quantities
    feats: dict                     # the core's features of every recording
    cfg: object                     # the core's configuration for the rig's records ...
    cfg_sim: object                 # ... and for the twin's (no channel delays)
    simulate: object                # fem.Simulator `simulate(params, rig, x, y, h)`, or None without the FEM
    noise: tuple                    # the rig noise added to simulations: (counts rms, realisations, seed)

    @property
    def rig(self):
        return self.session.rig


@dataclass(kw_only=True)
class CalibrationProblem(DropsAndTwin):
    """One calibration: its inputs (fixed once the drops are chosen) and the state the stages advance."""

    opts: CalibrateOptions
    data: str
    out: Path                       # CAL.json
    plate_targets: plate_fem.PlateTargets
    base_key: str                   # the cache key of the inputs every stage depends on
    e_axis: np.ndarray              # the plate grid
    nu_axis: np.ndarray
    clock: StageClock = field(default_factory=StageClock)
    params: dict = field(default_factory=dict)      # the twin's parameters as fitted so far
    plate: dict = field(default_factory=dict)       # CAL.json "plate"
    cal: dict = field(default_factory=dict)         # CAL.json's other blocks, in the stages' order
    stage_results: dict = field(default_factory=dict)   # each stage's result by stage name

    @property
    def stem(self) -> Path:
        return self.out.with_suffix("")

    def cache(self, tag: str) -> Path:
        """A stage cache's file next to CAL.json: `<stem>.<tag>`."""
        return Path(f"{self.stem}.{tag}")

    @property
    def e_bounds(self) -> tuple:
        return float(self.e_axis[0]), float(self.e_axis[-1])

    @property
    def nu_bounds(self) -> tuple:
        return float(self.nu_axis[0]), float(self.nu_axis[-1])

    def header(self) -> dict:
        """CAL.json's first fields: the data, the options, the core's picker and the drops used."""
        cfg, targets = self.cfg, self.targets
        return {"format": "impactsense-calibration/1", "data": str(Path(self.data)),
                "data_sha256": self.session.fingerprint(), "seed": self.opts.seed,
                "options": {k: v for k, v in asdict(self.opts).items() if k not in ("progress",)},
                "noise_added_to_simulations": {"counts_rms": self.noise[0], "realisations": self.noise[1]},
                "core_config": {"aic_blend": cfg.aic_blend, "rig_delay_us": list(cfg.rig_delay_us),
                                "fs_hz": cfg.fs_hz},
                "drops": targets.to_json(), "exclude_case_ids": [int(c) for c in targets.case_ids],
                "exclude_recording_ids": sorted(int(r) for rs in targets.recording_ids for r in rs)}


def check_out(out) -> Path:
    out = Path(out)
    if out.suffix.lower() != ".json":
        raise ConfigError(f"--out must name a .json file, got {out}")
    if out.exists() and out.is_dir():
        raise ConfigError(f"--out {out} is a directory")
    return out


def build_problem(data, out, opts: CalibrateOptions, simulate=None) -> CalibrationProblem:
    """Validate the options, load the session and choose its four drops (stage `drops`: repeatable cases the
    acceptance rule keeps, well spread over the plate) with their measured targets."""
    opts.validate()
    out = check_out(out)
    clock = StageClock()
    session = load_session(data)
    rig = session.rig
    cfg = measured_core_config(rig, opts)
    cfg_sim = sim_core_config(rig, opts)
    if simulate is None and opts.fem:
        simulate = fem.fem_simulator(workers=opts.workers)

    def choose_drops():
        feats = _core.extract_batch(core_samples(session.adc, cfg), cfg)
        t = drops_mod.select_drops(session, feats, opts.drops, tol_us=opts.eq35_tol_us,
                                   margin_mm=opts.eq35_margin_mm, min_reps=opts.min_reps)
        return t, plate_fem.measured_targets(session, t, feats, cfg), feats
    targets, plate_targets, feats = clock.run("drops", choose_drops)
    out.parent.mkdir(parents=True, exist_ok=True)   # only now: bad input has been rejected above
    noise = (float(np.median(targets.noise_rms)), int(opts.n_noise), int(opts.seed))
    base_key = key(session.fingerprint(), targets.to_json(), opts.aic_blend, channel_delays_us(cfg), noise)
    prior = priors.plate_grid_range(rig)
    nu_step = max(opts.nu_step, prior.pop("nu_step_min", 0.0))
    rng = {k: (v if getattr(opts, k) is None else getattr(opts, k)) for k, v in prior.items()}
    e_axis, nu_axis = plate.grid_axes(rng["e_min_mpa"], rng["e_max_mpa"], opts.e_step_mpa, rng["nu_min"],
                                      rng["nu_max"], nu_step)
    return CalibrationProblem(opts=opts, data=data, out=out, session=session, cfg=cfg, cfg_sim=cfg_sim,
                              simulate=simulate, feats=feats, targets=targets, plate_targets=plate_targets,
                              noise=noise, base_key=base_key, e_axis=e_axis, nu_axis=nu_axis, clock=clock)
