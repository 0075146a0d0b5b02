"""`SimParams`: every number the simulator needs that is not rig geometry, in one JSON.

Geometry (plate size, sensor centres, disc diameter, ball size and mass, sampling rate, ADC) always comes from
the rig (`impactsense.data.Rig`); `SimParams.from_rig` also copies the plate's density, thickness and support.

Defaults (documented, see docs/method.md):
- material: isotropic (e_pa, nu); with e2_pa and g12_pa set the plate is orthotropic (a laminate's smeared
  constants): e_pa is E1 and nu is nu12 along the material's axis 1, which lies material_axes_deg from the
  plate's x axis; g13_pa / g23_pa (transverse shear) default to g12_pa (`material.py`).
- plate: PMMA, E = 5000 MPa, nu = 0.32 (the seed's calibrated values), rho and t from the rig (1157 kg/m3,
  4.2 mm), Mindlin shear factor kappa = pi^2/12; support "simply_supported" (the rig's plate rests on a
  rubber rim: its edges cannot lift against the ball's load on the first arrivals we use, and they rotate
  freely). Also "free", "clamped", "simply_supported_soft" (w held on the edges, both rotations free: the
  Mindlin plate's soft simple support) and "elastic_rim": free edges on a rubber rim, a spring
  (rim_stiffness_n_m2, N/m per metre of edge) and a dashpot (rim_damping_n_s_m2, N s/m per metre) on w of
  every edge node, lumped by the node's share of the edge (stiffness 0: the free plate; very stiff: w held
  on the edges, the tangential rotation left free); rim_inset_mm moves the rim's line inside the edges. The springs enter the stability limit; the dashpot is
  explicit and must keep c dt / m <= 1 on the edge nodes.
- PZT block: the seed's fitted disc (E11 75200, E33 55200, G12 24800, G13 24900 MPa, nu12 0.30, nu13 0.34,
  rho 7531.4, eps11 3875.5, eps33 6320.2 relative, d15 50, d31 -737.8, d33 793 pC/N), ceramic 0.25 mm thick.
  The open-circuit disc is modelled by the thin-disc sensing law (see `model.py`): only d31, eps33, E11,
  nu12, rho and the thickness enter it; the other constants are carried for calibration and the record.
- damping D_s = 1086 1/s (seed), mass proportional.
- the discs' mechanical coupling, apart from what they sense: disc_patch_diameter_mm (None: the rig's
  sensor_diameter_mm) is the circle of plate under each disc centre that carries the ceramic's mass and bending
  stiffness (a smaller ceramic on a shim, or a bond that transfers strain only over part of the disc);
  disc_stiffness_scale (1) multiplies the ceramic's added bending stiffness (a compliant bond line: the ceramic
  then strains less than the plate's surface; 0 = disc_stiffness false) and disc_mass_scale (1) its added mass
  and rotary inertia (0 = disc_mass false). The sensing functional always averages over the rig's disc (its
  electrode). Defaults: the perfectly bonded disc, bit for bit.
- disc_inertia_factor 1.06: the rotary inertia under the discs (plate + ceramic) is raised by 6 % (never past the
  plate's D / I). The stiff disc elements set the explicit step, so the limit rises by about 3 % (at most
  sqrt(1.06)): the 1 mm mesh takes 29 steps per ADC sample instead of 30, the default mesh 14 instead of 15.
  The disc voltages and the DToA against the bundled recordings hardly move (docs/findings.md); a larger factor
  moves threshold picks by whole samples. 1.0 = the physical disc.
- disc_inertia_scaling (off): the ceramic's bending stiffness makes the elements under a disc ~4x stiffer in
  bending than the plate, and they set the explicit step (1 mm mesh: 0.348 us; 0.456 us without them).
  Turned on, the rotary inertia under each disc is raised (x1.73 for the rig's disc) so that its D / I
  equals the bare plate's: the step is then set by the plate (~24 % fewer steps). Selective rotary-inertia
  scaling, local to the 4 discs; it changes only what propagates under a disc (rotational inertia there).
- subcycle (on, for meshes of elements <= subcycle_max_element_mm = 1.5 mm): the stiff disc elements set the
  explicit step, so on fine meshes the four disc patches (the nodes of their elements) are sub-cycled: stepped
  m times per step with dt / m in their own limit while the rest of the plate takes the bare plate's step
  (nodal-partition multi-time-step central differences, Belytschko-Yen-Mullen: the ring of plate nodes around
  a patch moves linearly in time from u_n to u_{n+1} during the sub-steps; stable, energy conserved to 1e-3).
  1 mm mesh: 23 steps per ADC sample (2 sub-steps under the discs) instead of 29, disc voltages within 0.3 %
  RMS of the single-step scheme. The error sits at the patch boundary (linear interpolation of the ring) and
  grows with the element size and dt: 0.4-0.7 % at the default 2.1 mm mesh (11 steps instead of 14), so the
  default mesh is stepped plainly. subcycle = false turns it off everywhere.
- solver "direct" (the explicit FEM, the reference) or "modal" (modal superposition of the same FEM's modes,
  `modal.py`); loss_factor (0) adds a loss factor to every mode's damping (the direct solver's records get it
  after the run, `loss.py`);
  modal_cutoff_factor (2): the modal basis holds the modes up to this x f_max (Eq. 1's band, the band the mesh
  resolves; at 1 x the truncation rings at the cut-off ahead of the wave and onset picks move by ~3-7 us, at
  2 x under 1 us, docs/findings.md); the truncated modes enter as residual flexibility (contact and
  outputs); modal_poles "fem_step"
  (default): each mode oscillates as the direct solver's central-difference step makes it (its numerical
  dispersion, which the calibration absorbed), "exact": the continuous-time modes.
- circuit_gain 0.04: the open-circuit disc law gives tens of volts for a 150 mm drop, the bundled logger's ADC
  sees about a volt: the disc's capacitance is loaded by the input network (docs/findings.md).
- ball: steel E = 210 GPa, nu = 0.30; `from_rig` takes the rig's ball (rig.json `ball_material` in words, or
  `ball_properties`; balls.py).
- numerics: element size by Eq. 1 (L_e = lambda_A0(f_max) / 10 along the plate's softest direction, f_max =
  3 / T_contact of a Hertz impact from `max_height_mm` on a rigid-backed half space of the plate material,
  where the half-sine force spectrum's envelope is 30 dB down, but at most the logger's Nyquist frequency
  fs / 2: a stiff plate's short contact excites more than the logger records; about 2.1 mm for the rig. With 2 / T_contact (2.6 mm) the core's
  threshold ToA at far sensors moved up to 13 us against a 1 mm mesh; at 2.0 mm they agree within 3 us), dt by Eq. 2 and the assembled plate's stability limit (largest eigenvalue of M^-1 K by Lanczos; safety
  0.97, see `model.assembled_dt_crit`), snapped to divide the ADC period (1 mm mesh: limit 0.348 us, dt
  0.333 us; Eq. 2 would allow 1.6 us);
  6 ms simulated after the impact (99 % of the measured energy arrives within it), impact at sample 200.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from dataclasses import dataclass, fields
from pathlib import Path

from ..balls import ball_for_rig
from ..errors import ConfigError
from ..signal import baseline_for_pretrigger
from .material import fields_for_rig

FORMAT = "impactsense-sim-params"
SUPPORTS = ("free", "simply_supported", "simply_supported_soft", "clamped", "elastic_rim")
METHODS = ("auto", "fast", "direct")
SOLVERS = ("direct", "modal")


@dataclass(frozen=True)
class SimParams:
    # plate
    e_pa: float = 5.0e9                    # E (isotropic) or E1, along the material's axis 1 (orthotropic)
    nu: float = 0.32                       # nu (isotropic) or nu12 (orthotropic)
    e2_pa: float | None = None             # orthotropic: E2 across axis 1 (None: the plate is isotropic)
    g12_pa: float | None = None            # orthotropic: in-plane shear modulus G12
    g13_pa: float | None = None            # orthotropic: transverse shear moduli (None: G12)
    g23_pa: float | None = None
    material_axes_deg: float = 0.0         # orthotropic: axis 1 (the fibres) at this angle from the plate's x axis
    rho_kg_m3: float = 1157.0
    thickness_mm: float = 4.2
    support: str = "simply_supported"
    rim_stiffness_n_m2: float = 0.0       # elastic_rim: the rim's stiffness on w per metre of edge [N/m per m]
    rim_damping_n_s_m2: float = 0.0       # elastic_rim: its dashpot per metre of edge [N s/m per m]
    rim_inset_mm: float = 0.0             # elastic_rim: the rim's line this far inside the edges (overhang)
    shear_factor: float = math.pi ** 2 / 12
    damping_per_s: float = 1086.0          # D_s
    # PZT disc (docs/method.md block; relative permittivities, pC/N, MPa)
    pzt_rho_kg_m3: float = 7531.4
    pzt_e11_mpa: float = 75200.0
    pzt_e33_mpa: float = 55200.0
    pzt_nu12: float = 0.30
    pzt_nu13: float = 0.34
    pzt_g12_mpa: float = 24800.0
    pzt_g13_mpa: float = 24900.0
    pzt_d15_pc_n: float = 50.0
    pzt_d31_pc_n: float = -737.8
    pzt_d33_pc_n: float = 793.0
    pzt_eps11_rel: float = 3875.5
    pzt_eps33_rel: float = 6320.2
    pzt_thickness_mm: float = 0.25
    disc_mass: bool = True                 # add the ceramic's mass under each disc
    disc_stiffness: bool = True            # add the ceramic's bending stiffness under each disc
    disc_patch_diameter_mm: float | None = None  # the plate area the ceramic loads (mass, stiffness); None: the disc's
    disc_stiffness_scale: float = 1.0      # the ceramic's added bending stiffness x this (a compliant bond: < 1)
    disc_mass_scale: float = 1.0           # the ceramic's added mass and rotary inertia x this
    disc_inertia_scaling: bool = False     # opt-in: rotary inertia under the discs raised to the plate's D/I
    disc_inertia_factor: float = 1.06      # rotary inertia under the discs x this (capped at the plate's D/I)
    subcycle: bool = True                  # fine meshes: the disc patches stepped with dt / m, the plate at its limit
    subcycle_max_element_mm: float = 1.5   # sub-cycle only meshes this fine (the interface error grows with h)
    circuit_gain: float = 0.04             # ADC-input volts per disc volt (sign = wiring); fitted to the bundled peaks
    # ball
    ball_e_pa: float = 210e9
    ball_nu: float = 0.30
    g_m_s2: float = 9.80665
    # numerics
    element_mm: float | None = None        # None: Eq. 1
    f_max_hz: float | None = None          # None: f_max_factor / T_contact (Hertz at max_height_mm)
    f_max_factor: float = 3.0
    max_height_mm: float = 200.0
    dt_us: float | None = None             # None: Eq. 2 and stability (snapped to divide 1/fs)
    cfl_safety: float = 0.97               # dt <= cfl_safety x the assembled plate's stability limit
    rotary_inertia_scale: float = 1.0      # > 1 raises the stable dt (mass scaling); 1 = physical
    duration_ms: float = 6.0               # simulated time after the first touch
    taper_ms: float = 1.0                  # raised-cosine fade at the end of the simulated window
    contact_window_ms: float = 2.0         # fast path: longest direct contact solve
    pretrigger_samples: int = 200          # record sample of the first touch
    noise_counts_rms: float = 1.5          # used only when noise is asked for
    method: str = "auto"                   # "fast" (reciprocity), "direct", "auto": direct for <= 4 drops
    solver: str = "direct"                 # "direct": the explicit FEM (with `method`); "modal": its modes (sim.modal)
    loss_factor: float = 0.0               # a loss factor eta on top of D_s (s_k += eta omega_k / 2; direct: loss.py)
    modal_cutoff_factor: float = 2.0       # modal solver: modes up to this x f_max (the rest as residual flexibility)
    modal_poles: str = "fem_step"          # modal solver: "fem_step" (the direct solver's time step) or "exact"

    # ---- construction -------------------------------------------------------------------------------
    def __post_init__(self):
        self.validate()

    @classmethod
    def field_names(cls) -> list[str]:
        return [f.name for f in fields(cls)]

    @classmethod
    def from_dict(cls, raw: dict, where: str = "sim params") -> "SimParams":
        if not isinstance(raw, dict):
            raise ConfigError(f"{where}: must be a JSON object")
        raw = {k: v for k, v in raw.items() if k not in ("format", "version")}
        unknown = sorted(set(raw) - set(cls.field_names()))
        if unknown:
            raise ConfigError(f"{where}: unknown key(s) {unknown}; known: {cls.field_names()}")
        try:
            return cls(**raw)
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None
        except TypeError as exc:
            raise ConfigError(f"{where}: {exc}") from None

    @classmethod
    def from_json(cls, path: str | os.PathLike) -> "SimParams":
        path = Path(path)
        if not path.is_file():
            raise ConfigError(f"{path}: file not found")
        try:
            raw = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise ConfigError(f"{path}: not valid JSON ({exc})") from None
        if isinstance(raw, dict) and "sim_params" in raw and isinstance(raw["sim_params"], dict):
            raw = raw["sim_params"]  # a calibration file
        return cls.from_dict(raw, str(path))

    @classmethod
    def from_rig(cls, rig, **overrides) -> "SimParams":
        """Defaults with the rig's plate density, thickness, support and material (`material.fields_for_rig`) and
        its ball's elastic constants (`balls.ball_for_rig`)."""
        text = str(getattr(rig, "plate_support", "")).lower()
        if "clamp" in text:
            support = "clamped"
        elif "free" in text or "suspend" in text:
            support = "free"
        else:  # resting on a rim / simply supported
            support = "simply_supported"
        ball = ball_for_rig(rig)   # the impactor's E and nu (the table's steel when the words name no other)
        base = dict(rho_kg_m3=float(rig.density_kg_m3), thickness_mm=float(rig.thickness_mm), support=support,
                    ball_e_pa=ball.e_pa, ball_nu=ball.nu)
        pre = getattr(rig, "pretrigger_samples", None)
        if baseline_for_pretrigger(pre) is not None:  # a short pre-trigger: the twin's records start as the rig's
            base["pretrigger_samples"] = int(pre)
        base.update(overrides)
        base.update(fields_for_rig(rig, cls(), overrides))
        return cls.from_dict(base, "SimParams.from_rig")

    def to_dict(self) -> dict:
        return {"format": FORMAT, "version": 1, **dataclasses.asdict(self)}

    def to_json(self, path: str | os.PathLike) -> Path:
        path = Path(path)
        path.write_text(json.dumps(self.to_dict(), indent=1))
        return path

    def replace(self, **changes) -> "SimParams":
        return dataclasses.replace(self, **changes)

    # ---- validation ---------------------------------------------------------------------------------
    def _validate_orthotropic(self, num) -> None:
        num("material_axes_deg")
        if self.e2_pa is None:
            extra = [n for n in ("g12_pa", "g13_pa", "g23_pa") if getattr(self, n) is not None]
            if extra:
                raise ConfigError(f"{', '.join(extra)} set without e2_pa: an orthotropic plate needs e2_pa and "
                                  "g12_pa (e_pa is then E1, nu is nu12)")
            return
        num("e2_pa", 0)
        if self.g12_pa is None:
            raise ConfigError("an orthotropic plate (e2_pa set) needs g12_pa")
        num("g12_pa", 0)
        num("g13_pa", 0, allow_none=True)
        num("g23_pa", 0, allow_none=True)
        if self.nu ** 2 >= self.e_pa / self.e2_pa:
            raise ConfigError(f"nu12 = {self.nu!r} with E1/E2 = {self.e_pa / self.e2_pa:.3g}: the material is not "
                              "positive definite (needs nu12^2 < E1 / E2)")

    def validate(self) -> None:
        def num(name, lo=None, hi=None, lo_open=True, hi_open=True, allow_none=False):
            v = getattr(self, name)
            if v is None and allow_none:
                return
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ConfigError(f"{name} must be a finite number, got {v!r}")
            if lo is not None and (v <= lo if lo_open else v < lo):
                raise ConfigError(f"{name} must be {'>' if lo_open else '>='} {lo}, got {v!r}")
            if hi is not None and (v >= hi if hi_open else v > hi):
                raise ConfigError(f"{name} must be {'<' if hi_open else '<='} {hi}, got {v!r}")

        num("e_pa", 0)
        num("nu", -1, 0.5)
        self._validate_orthotropic(num)
        num("rho_kg_m3", 0)
        num("thickness_mm", 0)
        num("shear_factor", 0, 1, hi_open=False)
        num("damping_per_s", 0, lo_open=False)
        for name in ("pzt_rho_kg_m3", "pzt_e11_mpa", "pzt_e33_mpa", "pzt_g12_mpa", "pzt_g13_mpa",
                     "pzt_eps11_rel", "pzt_eps33_rel", "pzt_thickness_mm"):
            num(name, 0)
        num("pzt_nu12", -1, 0.5)
        num("pzt_nu13", -1, 0.5)
        for name in ("pzt_d15_pc_n", "pzt_d31_pc_n", "pzt_d33_pc_n", "circuit_gain"):
            num(name)
        num("ball_e_pa", 0)
        num("ball_nu", -1, 0.5)
        num("g_m_s2", 0, lo_open=False)
        num("element_mm", 0, allow_none=True)
        num("f_max_hz", 0, allow_none=True)
        num("max_height_mm", 0)
        num("f_max_factor", 0)
        num("dt_us", 0, allow_none=True)
        num("cfl_safety", 0, 1, hi_open=False)
        num("rotary_inertia_scale", 1, lo_open=False)
        num("disc_inertia_factor", 1, lo_open=False)
        num("subcycle_max_element_mm", 0, lo_open=False)
        num("duration_ms", 0)
        num("taper_ms", 0, lo_open=False)
        num("contact_window_ms", 0)
        num("noise_counts_rms", 0, lo_open=False)
        if self.taper_ms >= self.duration_ms:
            raise ConfigError(f"taper_ms ({self.taper_ms}) must be shorter than duration_ms ({self.duration_ms})")
        if isinstance(self.pretrigger_samples, bool) or not isinstance(self.pretrigger_samples, int) \
                or self.pretrigger_samples < 0:
            raise ConfigError(f"pretrigger_samples must be an integer >= 0, got {self.pretrigger_samples!r}")
        if self.support not in SUPPORTS:
            raise ConfigError(f"support must be one of {SUPPORTS}, got {self.support!r}")
        num("rim_stiffness_n_m2", 0, lo_open=False)
        num("rim_damping_n_s_m2", 0, lo_open=False)
        num("rim_inset_mm", 0, lo_open=False)
        if self.support != "elastic_rim" and (self.rim_stiffness_n_m2 or self.rim_damping_n_s_m2 or self.rim_inset_mm):
            raise ConfigError(f"rim_stiffness_n_m2 / rim_damping_n_s_m2 / rim_inset_mm are used only with support "
                              f"'elastic_rim', not {self.support!r}")
        if self.method not in METHODS:
            raise ConfigError(f"method must be one of {METHODS}, got {self.method!r}")
        if self.solver not in SOLVERS:
            raise ConfigError(f"solver must be one of {SOLVERS}, got {self.solver!r}")
        num("loss_factor", 0, lo_open=False)
        num("modal_cutoff_factor", 0)
        if self.modal_poles not in ("fem_step", "exact"):
            raise ConfigError(f"modal_poles must be 'fem_step' or 'exact', got {self.modal_poles!r}")
        num("disc_patch_diameter_mm", 0, allow_none=True)
        num("disc_stiffness_scale", 0, lo_open=False)
        num("disc_mass_scale", 0, lo_open=False)
        for name in ("disc_mass", "disc_stiffness", "disc_inertia_scaling", "subcycle"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"{name} must be true or false")
