"""`impactsense calibrate`'s options: what the user chooses, validated in one place."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError
from ..sim.params import SUPPORTS
from . import fem

MIN_BUDGET = 24   # 70/15/15 of 24 = 17/4/3 runs: the smallest design the split and the screening can use


@dataclass
class CalibrateOptions:
    drops: object = "auto"                 # "auto" or four case ids
    budget: int = 32                       # FEM runs in the PZT design (stage `design`; why 32: docs/findings.md,
                                           # "The cold chain under 180 CPU-s")
    seed: int = 0
    workers: int = 2
    progress: bool = True
    e_min_mpa: float | None = None         # the plate grid's range; None: the rig material's priors (priors.py)
    e_max_mpa: float | None = None
    e_step_mpa: float = 250.0
    nu_min: float | None = None
    nu_max: float | None = None
    nu_step: float = 0.001
    aic_blend: float = 1.0                 # core ToA: 1 = AIC onset (amplitude-independent), 0 = threshold
    rig_delay_us: list | None = None       # known per-channel delays of the rig; default: rig.json's, else 0
    eq35_tol_us: float = 0.0
    eq35_margin_mm: float = 0.0
    min_reps: int = 2
    surrogate_trials: int = 8
    fem: bool = True                       # False: the plate grid only (no FEM confirmation, no PZT design)
    plate_only: bool = False               # True: the plate stages only (grid, laminate, the FEM's E scan)
    design: bool = True                    # False: no PZT design (the seed's PZT block; D_s the plate stages')
    fast_n_fft: int = 1024
    fem_e_ratios: tuple = (0.7, 0.8, 0.9, 1.0, 1.1)   # FEM plate fit: E basin scan = fast minimum x these
    n_noise: int = 4                       # rig-noise realisations added to simulated records before picking
    nu_rounds: int = 2                     # nu stage: rounds of (positions, then E, nu, D_s); 0 skips the stage
    # plate support: "rig" (rig.json's text, SimParams.from_rig), a SimParams support, or "auto": the candidate
    # (plate_nu.SUPPORT_CANDIDATES) whose group delays fit best (stage `support`, after `damping`)
    support: str = "rig"
    rim_stiffness_n_m2: float | None = None  # support "elastic_rim": the rim's stiffness per metre of edge
    # the discs' bond: "off" (the bonded ceramic, disc_stiffness_scale 1) or "fit" (stage `disc_bond`)
    disc_bond: str = "off"
    # the twin's mesh: Eq. 1's, but at most this many elements (fem.capped_mesh; written into CAL.json's
    # sim_params as element_mm when it binds); None: Eq. 1's mesh whatever its size
    max_elements: int | None = 30_000
    # the twin's span (sim_params duration_ms): "measured" (calibration.span's rule) or "default" (the simulator's)
    twin_span: str = "measured"

    def validate(self):
        if not isinstance(self.budget, (int, np.integer)) or self.budget < MIN_BUDGET:
            raise ConfigError(f"--budget {self.budget} is too small for the PZT design: the 70/15/15 "
                              f"split and the factor screening of {len(fem.FACTORS)} factors need at least "
                              f"{MIN_BUDGET} FEM runs")
        if self.e_step_mpa <= 0 or self.nu_step <= 0:
            raise ConfigError("the E / nu grid needs positive steps")
        e_lo, e_hi = (1.0 if v is None else v for v in (self.e_min_mpa, self.e_max_mpa))
        nu_lo, nu_hi = (0.0 if v is None else v for v in (self.nu_min, self.nu_max))
        if (self.e_max_mpa is not None and self.e_max_mpa < e_lo) or (self.nu_max is not None and nu_hi < nu_lo):
            raise ConfigError("the E / nu grid needs max >= min")
        if e_lo <= 0 or e_hi <= 0 or not (0.0 <= nu_lo and nu_hi < 0.5):
            raise ConfigError("the E / nu grid must stay physical: E > 0, 0 <= nu < 0.5")
        if self.max_elements is not None and not (isinstance(self.max_elements, (int, np.integer))
                                                  and self.max_elements >= 100):
            raise ConfigError(f"--max-elements must be a whole number >= 100, got {self.max_elements!r}")
        if self.workers < 1:
            raise ConfigError("--workers must be >= 1")
        if self.twin_span not in ("measured", "default"):
            raise ConfigError(f"--twin-span must be 'measured' or 'default', got {self.twin_span!r}")
        if not isinstance(self.nu_rounds, (int, np.integer)) or self.nu_rounds < 0:
            raise ConfigError(f"nu_rounds must be a whole number >= 0, got {self.nu_rounds!r}")
        if self.support not in ("rig", "auto", *SUPPORTS):
            raise ConfigError(f"--support must be one of {('rig', 'auto', *SUPPORTS)}, got {self.support!r}")
        if self.support == "elastic_rim" and not (self.rim_stiffness_n_m2 is not None and self.rim_stiffness_n_m2 >= 0):
            raise ConfigError("--support elastic_rim needs --rim-stiffness (N/m per metre of edge, >= 0)")
        if self.support != "elastic_rim" and self.rim_stiffness_n_m2 is not None:
            raise ConfigError("--rim-stiffness is used only with --support elastic_rim")
        if self.disc_bond not in ("off", "fit"):
            raise ConfigError(f"--disc-bond must be 'off' or 'fit', got {self.disc_bond!r}")
        if self.disc_bond == "fit" and not self.fem:
            raise ConfigError("--disc-bond fit compares the FEM's group delays: it needs the FEM (drop --no-fem)")
        if self.support == "auto" and not self.fem:
            raise ConfigError("--support auto compares the FEM's group delays: it needs the FEM (drop --no-fem)")
