"""The twin's loss factor (docs/method.md "The twin's loss factor"): the direct solver's records damped per
frequency as the modal solver's poles (`sim.loss`), and calibrate's rule that reads it from the rig's decay per band
(`calibration.loss`)."""

from __future__ import annotations

import numpy as np
import pytest

from impactsense.calibration import loss

FS = 100_000.0
N = 3000
ONSET = 500


def envelope_rate(x: np.ndarray, f0: float, t: np.ndarray) -> float:
    """Amplitude decay rate [1/s] of x's component at f0: the log of its 0.5 ms windowed projections' magnitude."""
    w = 50
    mags, times = [], []
    for k in range(0, x.size - w, w):
        seg = x[k:k + w]
        mags.append(abs(np.sum(seg * np.exp(-2j * np.pi * f0 * t[k:k + w]))))
        times.append(t[k + w // 2])
    return -np.polyfit(times, np.log(mags), 1)[0]


def test_each_frequency_decays_by_its_own_loss_and_no_loss_changes_nothing():
    from impactsense.sim.loss import apply_loss_factor

    t = np.arange(1000) / FS                      # 10 ms from the touch
    eta = 0.008
    x = np.sin(2 * np.pi * 3000 * t) + np.sin(2 * np.pi * 25000 * t + 0.3)
    y = apply_loss_factor(x[None, None], FS, eta)[0, 0]
    for f0 in (3000.0, 25000.0):                  # amplitude rate eta pi f, each component its own
        assert envelope_rate(y[50:-50], f0, t[50:-50]) == pytest.approx(eta * np.pi * f0, rel=0.03)
    assert np.max(np.abs(y[:5] - x[:5])) < 0.02   # at the touch nothing is lost yet
    same = apply_loss_factor(x, FS, 0.0)
    assert same is x


def ringing(rates_of_f, rng, drops: int = 4) -> np.ndarray:
    """ADC-like records [drops, 4, N]: from ONSET many modes between 0.8 and 40 kHz, each decaying (energy) at
    rates_of_f(f), plus white noise."""
    t = (np.arange(N) - ONSET) / FS
    out = np.zeros((drops, 4, N))
    f = rng.uniform(800, 40000, 120)
    for d in range(drops):
        for c in range(4):
            a, ph = rng.normal(size=f.size), rng.uniform(0, 2 * np.pi, f.size)
            env = np.exp(-0.5 * rates_of_f(f)[:, None] * np.clip(t, 0, None)[None, :]) * (t >= 0)
            out[d, c] = (a[:, None] * env * np.sin(2 * np.pi * f[:, None] * t[None, :] + ph[:, None])).sum(0)
    out *= 400 / np.abs(out).max()
    return 2048 + out + rng.normal(scale=1.5, size=out.shape)


def test_a_decay_that_rises_with_frequency_gives_its_loss_factor_and_a_flat_one_none():
    rng = np.random.default_rng(3)
    eta, ds = 0.006, 300.0
    rising = loss.decay_by_band(ringing(lambda f: ds + eta * 2 * np.pi * f, rng), 2048, FS)
    fit = loss.fit_loss(rising, d_s=500.0)
    assert fit["kept"] and fit["z"] >= loss.Z_MIN and fit["intercept_per_s"] > 0
    assert fit["loss_factor"] == pytest.approx(eta, rel=0.2)
    # the twin keeps the broadband decay: its D_s falls by what the line puts above its intercept there
    assert fit["damping_per_s"] == pytest.approx(500.0 - (rising["broadband_rate_per_s"] - fit["intercept_per_s"]))
    assert fit["damping_per_s"] < 500.0
    flat = loss.fit_loss(loss.decay_by_band(ringing(lambda f: np.full_like(f, 700.0), rng), 2048, FS), d_s=500.0)
    assert not flat["kept"] and flat["loss_factor"] == 0.0 and flat["damping_per_s"] == 500.0
    assert flat["rate_per_s"][2] == pytest.approx(700.0, rel=0.15)


def test_a_flat_decay_read_through_scattered_channels_gets_no_loss_factor():
    """A flat plate (every frequency at 600 1/s) read on two drops whose channels ring +-40 % apart (each its own
    rate): the bands' medians wobble, and on some draws the line tilts up 1.5 x over the bands (a rise-only rule
    would fire), but never by 3 of its standard errors from the channels' own scatter: the twin keeps D_s."""
    rises = []
    for seed in range(10):
        rng = np.random.default_rng(seed)
        out = np.concatenate([ringing(lambda f, k=rng.lognormal(0.0, 0.4): k * np.full_like(f, 600.0), rng, drops=1)
                              for _ in range(2)])
        fit = loss.fit_loss(loss.decay_by_band(out, 2048, FS), d_s=500.0)
        assert not fit["kept"] and fit["z"] < loss.Z_MIN and fit["damping_per_s"] == 500.0, seed
        rises.append(fit["rise"])
    assert max(rises) >= 1.5           # the draws do tilt: the significance, not the size, refuses them


def test_a_passing_wave_is_not_a_loss_factor():
    """A record with no ringing field, only a dispersive wave passing the sensor (its high frequencies first):
    each band's energy falls as its part of the wave leaves, faster in the high bands, but the line through those
    "decays" leaves no damping under it (negative intercept): no loss factor, D_s as it was."""
    t = (np.arange(N) - ONSET) / FS
    out = np.zeros((4, 4, N))
    rng = np.random.default_rng(2)
    for d in range(4):
        for c in range(4):
            dist = rng.uniform(0.1, 0.4)                  # m; flexural group velocity ~ 2 sqrt(f) m/s per sqrt(Hz)
            for f in np.geomspace(800, 40000, 200):
                tg = dist / (2.0 * np.sqrt(f))
                out[d, c] += np.exp(-0.5 * ((t - tg) / (0.25 * tg)) ** 2) * np.sin(2 * np.pi * f * t) / np.sqrt(f)
    out = 2048 + out * 400 / np.abs(out).max() + rng.normal(scale=1.5, size=out.shape)
    fit = loss.fit_loss(loss.decay_by_band(out, 2048, FS), d_s=650.0)
    assert not fit["kept"] and fit["loss_factor"] == 0.0 and fit["damping_per_s"] == 650.0


def test_too_few_readable_bands_keep_the_twin():
    rng = np.random.default_rng(0)
    quiet = 2048 + rng.normal(scale=1.5, size=(2, 4, N))     # noise only: no decay above it
    fit = loss.fit_loss(loss.decay_by_band(quiet, 2048, FS), d_s=400.0)
    assert not fit["kept"] and fit["loss_factor"] == 0.0 and fit["damping_per_s"] == 400.0


def test_the_direct_solvers_lossy_drop_matches_the_modal_solvers(tmp_path, monkeypatch):
    """The same small plate and drop, loss factor 0.01: the direct solver's records damped after the run against
    the modal solver's lossy poles (the modal test's bounds: waveform correlation >= 0.995, energies within 2 %),
    while the loss itself takes more than 10 % of the energy."""
    from test_sim_modal import small_rig

    from impactsense.sim import SimParams, simulate_voltages

    monkeypatch.setenv("IMPACTSENSE_MODAL_CACHE", str(tmp_path / "modal-cache"))
    rig = small_rig(160.0, 140.0)
    kw = dict(element_mm=5.0, duration_ms=2.0, taper_ms=0.2)
    lossy = SimParams.from_rig(rig, loss_factor=0.01, **kw)
    x, y, h = [75.0], [62.0], [150.0]
    direct = simulate_voltages(lossy, rig, x, y, h, solver="direct", workers=1)["volts"][0]
    modal = simulate_voltages(lossy, rig, x, y, h, solver="modal", workers=1)["volts"][0]
    plain = simulate_voltages(SimParams.from_rig(rig, **kw), rig, x, y, h, solver="direct", workers=1)["volts"][0]
    for s in range(4):
        assert np.corrcoef(direct[s], modal[s])[0, 1] >= 0.995
        assert abs(np.sum(direct[s] ** 2) / np.sum(modal[s] ** 2) - 1) <= 0.02
        assert np.sum(direct[s] ** 2) < 0.9 * np.sum(plain[s] ** 2)
