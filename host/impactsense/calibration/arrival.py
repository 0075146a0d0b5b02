"""Fast first-arrival model for sub-problem 1: an infinite Mindlin plate hit by a Hertz force pulse.

Why this is enough for the plate grid: the first arrival at a sensor is the fastest part of the direct A0
wave; edge reflections and the PZT discs arrive or act later. It depends on the plate (E, nu, rho, t) and
on the contact pulse only. The model is evaluated in the frequency domain:

  Mindlin's plate equation (time-harmonic, e^{+i w t}) factorises as D (lap + K1)(lap + K2) w = (1 - D lap/S
  - I w^2/S) q, with K1,2 the roots of the dispersion relation D K^2 - (I w^2 + a D) K + a I w^2 - m w^2 = 0,
  a = rho w^2 / (kappa G), S = kappa G t, I = rho t^3 / 12, m = rho t (Mindlin 1951). The point-force Green
  function is G4 = (g1 - g2) / (K1 - K2), g_K = (-i/4) H0^(2)(sqrt(K) r); the surface in-plane strain sensed
  by a disc is proportional to div(psi) = (K_j - m w^2 / S) w_j per branch. The disc average of H0 over a
  disc of radius a at distance R > a is H0(kR) 2 J1(ka)/(ka) (Graf's addition theorem). Only the
  propagating A0 branch K1 is kept: the second branch is evanescent below its cut-off (about 170 kHz for the
  rig's plate, far above the 50 kHz Nyquist limit) and decays within millimetres. H0 is evaluated with its
  two-term large-argument expansion (kr > 5 for every frequency that reaches the onset).

  The force is the Hertz half-sine pulse of a rigid-on-elastic contact: duration T_c = 2.94 delta_max / v,
  delta_max = (15 m v^2 / (16 E* sqrt(R)))^(2/5), v = sqrt(2 g h).

The synthetic voltage is high-passed at `highpass_hz` (the disc's electrical high-pass; it removes the
slow, late low-frequency tail that would wrap around the FFT window) and cut before the fastest A0 arrival
(causality). `plate.fast_loss` scales it to ADC counts (peak = the measured channel's peak), adds the rig's
noise and picks it with the SAME signal core (`impactsense._core.extract_batch`) as the measured drops.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


KAPPA = np.pi ** 2 / 12.0      # Mindlin shear correction
G0 = 9.80665                   # m/s^2
STEEL_E_PA = 210e9
STEEL_NU = 0.30


@dataclass(frozen=True)
class ArrivalSetup:
    """Geometry of the drops the model is evaluated at (all SI)."""

    r_m: np.ndarray          # [n_drops, 4] impact-to-sensor-centre distances
    height_m: np.ndarray     # [n_drops]
    disc_radius_m: float
    thickness_m: float
    density_kg_m3: float
    ball_radius_m: float
    ball_mass_kg: float
    fs_hz: float
    n_fft: int = 2048
    t_impact_s: float = 1.5e-3
    highpass_hz: float = 1000.0
    ball_e_pa: float = STEEL_E_PA     # the ball's constants for the Hertz contact (balls.ball_for_rig)
    ball_nu: float = STEEL_NU


FAST_SPAN_ARRIVALS = 2.0   # the fast model's record spans the impact time and this x the farthest arrival


def span_n_fft(rig, n_fft: int, t_impact_s: float = ArrivalSetup.t_impact_s) -> int:
    """`n_fft`, or the next power of two that spans the impact time plus FAST_SPAN_ARRIVALS x the plate's diagonal
    at its slowest flexural group velocity (record_window.slowest_velocity_mm_per_us) where `n_fft` samples at the
    rig's rate do not (a fast logger: 1024 samples at 1 MHz end before the impact at 1.5 ms, and every
    synthetic drop went without a pick), at most the core's CORE_MAX_SAMPLES. A sample count, not a time, was
    the option; at 100 kHz and slower rates the default spans far more and is kept."""
    from ..record_window import slowest_velocity_mm_per_us
    from ..signal import CORE_MAX_SAMPLES

    diag_mm = float(np.hypot(rig.plate_x_mm, rig.plate_y_mm))
    need = (t_impact_s + FAST_SPAN_ARRIVALS * diag_mm / slowest_velocity_mm_per_us(rig) * 1e-6) * float(rig.fs_hz)
    if n_fft >= need:
        return int(n_fft)
    return int(min(2 ** int(np.ceil(np.log2(need))), max(CORE_MAX_SAMPLES, n_fft)))


def setup_from_rig(rig, x_mm, y_mm, height_mm, *, n_fft: int = 2048) -> ArrivalSetup:
    from ..balls import ball_for_rig

    n_fft = span_n_fft(rig, n_fft)
    ball = ball_for_rig(rig)
    sx, sy = rig.sensor_x_mm.astype(float), rig.sensor_y_mm.astype(float)
    x = np.asarray(x_mm, float)[:, None]
    y = np.asarray(y_mm, float)[:, None]
    r_mm = np.hypot(x - sx[None, :], y - sy[None, :])
    return ArrivalSetup(
        r_m=r_mm * 1e-3, height_m=np.asarray(height_mm, float) * 1e-3,
        disc_radius_m=rig.sensor_diameter_mm * 0.5e-3, thickness_m=rig.thickness_mm * 1e-3,
        density_kg_m3=rig.density_kg_m3, ball_radius_m=rig.ball_diameter_mm * 0.5e-3,
        ball_mass_kg=rig.ball_mass_g * 1e-3, fs_hz=float(rig.fs_hz), n_fft=n_fft, ball_e_pa=ball.e_pa,
        ball_nu=ball.nu)


def a0_wavenumber(omega, e_pa, nu, rho, t_m):
    """Mindlin A0 wavenumber k1 [rad/m] (the simulator's `sim.dispersion`, one copy of the relation) and the
    plate constants D, S = kappa G t, m = rho t used by the Green function (broadcasts)."""
    from ..sim import dispersion
    omega = np.asarray(omega, float)
    k1 = dispersion.a0_wavenumber(omega / (2 * np.pi), e_pa, nu, rho, t_m, KAPPA)
    g = e_pa / (2.0 * (1.0 + nu))
    d = e_pa * t_m ** 3 / (12.0 * (1.0 - nu ** 2))
    return k1, k1 * k1, d, KAPPA * g * t_m, rho * t_m


def hertz_duration_s(e_pa, nu, height_m, ball_radius_m, ball_mass_kg, ball_e_pa=STEEL_E_PA, ball_nu=STEEL_NU):
    """Hertz contact duration of a ball (default steel) on an elastic half-space of the plate material."""
    e_star = 1.0 / ((1.0 - nu ** 2) / e_pa + (1.0 - ball_nu ** 2) / ball_e_pa)
    v = np.sqrt(2.0 * G0 * height_m)
    delta = (15.0 * ball_mass_kg * v ** 2 / (16.0 * e_star * np.sqrt(ball_radius_m))) ** 0.4
    return 2.94 * delta / v


def _half_sine_spectrum(omega, tc):
    """Fourier transform of sin(pi t / tc) on [0, tc] (unit amplitude), e^{-i w t} kernel."""
    a = np.pi / tc
    den = a * a - omega * omega
    near = np.abs(den) < 1e-9 * a * a
    den = np.where(near, 1.0, den)
    val = a * (1.0 + np.exp(-1j * omega * tc)) / den
    return np.where(near, -0.5j * tc, val)


def synth_unit(setup: ArrivalSetup, e_pa, nu) -> np.ndarray:
    """Unit-gain synthetic sensor signals for a batch of plates.

    e_pa, nu: arrays [P]. Returns float64 [P, n_drops, 4, n_fft] (arbitrary units, impact at t_impact_s).
    """
    e_pa = np.atleast_1d(np.asarray(e_pa, float))[:, None]
    nu = np.atleast_1d(np.asarray(nu, float))[:, None]
    f, w = _band(setup)
    k1, k1sq, d, s, m = a0_wavenumber(w, e_pa, nu, setup.density_kg_m3, setup.thickness_m)
    # second root for the partial-fraction coefficient (exact product of roots)
    g = e_pa / (2 * (1 + nu))
    amp = _branch_amplitude(setup, w, k1sq, d, s, m, KAPPA * g)
    tc = hertz_duration_s(e_pa[:, :, None], nu[:, :, None], setup.height_m[None, :, None],
                          setup.ball_radius_m, setup.ball_mass_kg, setup.ball_e_pa, setup.ball_nu)   # [P, D, 1]
    return _synthesise(setup, f, w, k1[:, None, None, :], amp[:, None, None, :], tc)


def synth_unit_paths(setup: ArrivalSetup, k1, d, s, tc) -> np.ndarray:
    """Unit-gain synthetic signals when every drop-to-sensor path has its own plate: the A0 wavenumber
    k1 [P, D, 4, F] on the model's band (`band_hz`), and that path's bending stiffness d [P, D, 4, 1], shear
    stiffness s [P, D, 4, 1] and the drops' Hertz contact durations tc [P, D, 1] (a laminate's rays,
    `calibration.laminate`). Returns float64 [P, D, 4, n_fft] like `synth_unit`."""
    f, w = _band(setup)
    m = setup.density_kg_m3 * setup.thickness_m
    amp = _branch_amplitude(setup, w, k1 * k1, d, s, m, s / setup.thickness_m)
    return _synthesise(setup, f, w, k1, amp, tc)


def band_hz(setup: ArrivalSetup) -> np.ndarray:
    """The model's frequencies (the rFFT bins without DC) [F]."""
    return _band(setup)[0]


def _band(setup: ArrivalSetup):
    f = np.fft.rfftfreq(setup.n_fft, 1.0 / setup.fs_hz)[1:]            # skip DC
    return f, 2 * np.pi * f[None, :]


def _branch_amplitude(setup, w, k1sq, d, s, m, kappa_g):
    """The propagating branch's coefficient of the Green function times the disc's strain factor."""
    a = setup.density_kg_m3 * w ** 2 / kappa_g
    inertia = setup.density_kg_m3 * setup.thickness_m ** 3 / 12
    k2sq = (a * inertia * w ** 2 - m * w ** 2) / (d * k1sq)
    return (1.0 + d * k1sq / s - inertia * w ** 2 / s) / (d * (k1sq - k2sq)) * (k1sq - m * w ** 2 / s)


def _synthesise(setup, f, w, k1, amp, tc):
    """Signals [P, D, 4, n] from the branch k1 and amplitude (both broadcast to [P, D, 4, F]) and the contact
    durations tc [P, D, 1]: disc aperture, electrical high-pass, Hertz pulse, far-field H0, causal front."""
    n = setup.n_fft
    ka = k1 * setup.disc_radius_m
    from scipy.special import j1
    aperture = 2.0 * j1(ka) / ka
    hp = np.clip((f - 0.5 * setup.highpass_hz) / (0.5 * setup.highpass_hz), 0.0, 1.0)
    hp = 0.5 - 0.5 * np.cos(np.pi * hp)
    spec_common = amp * aperture * hp                                        # [P | 1, D | 1, 4 | 1, F]
    force = _half_sine_spectrum(w[:, None, :], tc)                           # [P, D, F]
    kr = k1 * setup.r_m[None, :, :, None]                                    # [P, D, 4, F]
    # H0^(2)(x) ~ sqrt(2/(pi x)) exp(-i(x - pi/4)) (1 + i/(8x)) ; outgoing for e^{+i w t}
    h0 = np.sqrt(2.0 / (np.pi * kr)) * np.exp(-1j * (kr - np.pi / 4)) * (1 + 1j / (8 * kr))
    delay = np.exp(-1j * w * setup.t_impact_s)                               # [1, F]
    spec = (-0.25j) * h0 * (spec_common * delay) * force[:, :, None, :]
    full = np.zeros(spec.shape[:-1] + (n // 2 + 1,), complex)
    full[..., 1:] = spec
    sig = np.fft.irfft(full, n=n, axis=-1)
    # causality: nothing arrives before the fastest A0 component of the band (group velocity at the top
    # frequency); this removes the circular wrap-around of the slow low-frequency tail
    cg_max = (w[0, -1] - w[0, -2]) / (k1[..., -1] - k1[..., -2])             # [P | 1, D | 1, 4 | 1]
    t = np.arange(n) / setup.fs_hz
    t_front = setup.t_impact_s + setup.r_m[None, :, :] / cg_max               # [P, D, 4]
    ramp = np.clip((t[None, None, None, :] - t_front[..., None]) * setup.fs_hz / 4.0 + 1.0, 0.0, 1.0)
    return sig * ramp


def to_counts(unit: np.ndarray, gain: np.ndarray, bias: int, adc_max: int) -> np.ndarray:
    """Scale unit signals [..., 4, S] by gain [..., 4] and quantise to int16 ADC counts."""
    x = np.rint(unit * gain[..., None] + bias)
    return np.clip(x, 0, adc_max).astype(np.int16)
