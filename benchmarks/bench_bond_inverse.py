"""The bond row's four-channel model with the core's bond inverse, under variants of the inverse and of the
training drops' bond: what is left between it and the unchanged sessions (docs/findings.md "Session 25: bond6").

On a loop session folder (`benchmarks/loop_sessions.py`; REF "ref", the bond session NAME): diagnose and
`loop.fit_bond` as `impactsense retrain`, the measured training drops (`loop.measured_training_session`), then per
variant the four-channel model (`loop.pick_settings`, 30 trees, the seed's forests, the delays carried) scored on
NAME. Variants (comma list):

- base: as retrain (fit_bond's one-pole in the training drops, the inverse at fc, g, f2 = BOND_LIMIT_OF_PICK x
  the other channels' pick frequency);
- kX: the same with f2 = X x that pick frequency;
- truth: the training drops' bond and the inverse both the session's true one-pole (the manifest's), f2 as base;
- truthinv: fit_bond's bond in the training drops, the inverse the true one-pole's;
- spectral: the one-pole sized by `spectral_one_pole` (the bonded channel's spectrum against the
  reference's at the same positions, the other channels' ratio taken out) in the training drops and the inverse;
- fX: base with the core's onset_noise_factor X (the absolute threshold and AIC blend refitted by train);
- wX: base with the physics position's bonded channel weighted as a pick X x as scattered as the others' (its
  Huber-IRLS residual over X): `weighted_phys` shifts the core's position by the difference of a Python
  weighted and unweighted fit of the same picks (a prototype of a per-channel weight in the localiser); wm: X the
  training drops' own lag rms on the bonded channel over the others' median (base must run first)
  (docs/findings.md "Session 28: bondloop2");
- pX[oN]: base's inverse (fc, g, f2) applied to the whole record in Python (`prefiltered`) and then N (default 1)
  one-poles at f3 = X x the other channels' pick frequency, on the training drops and on NAME alike, fed to the
  core as a plain channel (its inverse off); p0: the inverse alone (base on the whole record instead of the span)
  (docs/findings.md "Session 27: bondloop").

Per variant printed: MAE per axis (mm) and its ratio to UNCHANGED (the reference model's mean on same-1..3, given
or measured), and the bonded channel's pick lag (onset less travel less the other channels' mean, the model's
picks) on NAME less the training drops' cubic in position: mean and rms (us), beside the same for each other
channel (the lag of channel k against the rest).

    python benchmarks/bench_bond_inverse.py SESSIONS --seed S [--variants base,k0.35,truth] [--unchanged MM]
        [--forest-seed F] [--cache FILE]
"""

from __future__ import annotations

import argparse
import warnings
import dataclasses
import json
import pickle
import tempfile
import time
from pathlib import Path

import numpy as np

from impactsense import bond_inverse, loop
from impactsense.commands.retrain import carry_delays, score
from impactsense.data import load_session
from impactsense.diagnose import Candidate
from impactsense.loop import channel_delays, measured_training_session, pick_settings
from impactsense.models import ForestSettings
from impactsense.pipeline import featurize
from impactsense.workflow import train

from bench_bond_picks import cubic
from benchlib import sized_bond


SPECTRAL_BAND_HZ = (500.0, 30000.0)   # the one-pole's magnitude fitted in this band (below 0.4 fs)
SPECTRAL_MIN_SNR = 2.0                 # ... on bins where the bonded channel's power is this x its noise's
PRETRIGGER = 64                        # a record's first samples: its noise


def _spectra(session) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(f, P, noise): each channel's power spectrum averaged over drops, its noise's (the first PRETRIGGER samples'
    variance, white) taken out: P (n_freq, 4), and that noise per channel."""
    x = np.asarray(session.adc, float)
    x = x - x[:, :, :PRETRIGGER].mean(axis=2, keepdims=True)
    n = x.shape[2]
    p = (np.abs(np.fft.rfft(x, axis=2)) ** 2).mean(axis=0).T
    noise = n * x[:, :, :PRETRIGGER].var(axis=2).mean(axis=0)
    return np.fft.rfftfreq(n, 1.0 / float(session.rig.fs_hz)), p - noise[None, :], noise


def spectral_one_pole(reference, data, channel: int) -> tuple[float, float]:
    """(fc, g): the first-order low-pass g / (1 + j f / fc) whose magnitude best gives `data`'s power spectrum of
    `channel` from `reference`'s (each averaged over its drops, noise taken out), the other channels' median ratio
    taken out (what the two sessions' drops differ in for every channel): |H|^2 = (P_new / P_ref)_channel /
    median over the others of the same, fitted in log over SPECTRAL_BAND_HZ on bins the channel's power stands
    SPECTRAL_MIN_SNR above its noise in both sessions (a measurement: retrain sizes the bond with loop.fit_bond)."""
    from scipy.optimize import least_squares

    f, p_ref, n_ref = _spectra(reference)
    _, p_new, n_new = _spectra(data)
    others = [k for k in range(p_ref.shape[1]) if k != channel]
    fs = float(reference.rig.fs_hz)
    band = (f >= SPECTRAL_BAND_HZ[0]) & (f <= min(SPECTRAL_BAND_HZ[1], 0.4 * fs))
    band &= (p_ref[:, channel] > SPECTRAL_MIN_SNR * n_ref[channel]) & (p_new[:, channel] > SPECTRAL_MIN_SNR * n_new[channel])
    band &= (p_ref[:, others] > 0).all(axis=1) & (p_new[:, others] > 0).all(axis=1)
    if band.sum() < 5:
        raise ValueError(f"channel {channel}: too few bins above the noise for a bond's spectrum ({int(band.sum())})")
    common = np.median(p_new[band][:, others] / p_ref[band][:, others], axis=1)
    h2 = p_new[band, channel] / p_ref[band, channel] / common
    fb = f[band]

    def resid(q):
        fc, g = np.exp(q)
        return np.log(h2) - np.log(g * g / (1.0 + (fb / fc) ** 2))

    fit = least_squares(resid, [np.log(3000.0), np.log(0.7)], loss="soft_l1", f_scale=0.3)
    fc, g = np.exp(fit.x)
    return float(fc), float(g)


def lag_all(session, cfg) -> np.ndarray:
    """(n, 4): each channel's onset less the travel time less the other channels' mean of the same (us)."""
    toa = np.asarray(featurize(session.adc, cfg).toa_us, float)
    d = np.linalg.norm(session.xy_mm[:, None, :] - np.asarray(cfg.sensor_xy_mm, float)[None], axis=2)
    t = toa - d / float(cfg.velocity_mm_per_us)
    return np.stack([t[:, k] - np.nanmean(np.delete(t, k, axis=1), axis=1) for k in range(4)], 1)


def lag_residual(train_s, sess, cfg) -> list[tuple[float, float]]:
    """Per channel: (mean, rms) of the session's lag less the training drops' cubic in position (us)."""
    a, b = lag_all(train_s, cfg), lag_all(sess, cfg)
    out = []
    for k in range(4):
        ok = np.isfinite(a[:, k])
        coef = np.linalg.lstsq(cubic(train_s.xy_mm[ok], train_s.rig), a[ok, k], rcond=None)[0]
        e = b[:, k] - cubic(sess.xy_mm, sess.rig) @ coef
        e = e[np.isfinite(e)]
        out.append((float(e.mean()), float(np.sqrt(np.mean(e ** 2)))))
    return out


def with_bond(accepted, ch: int, fc: float, gain: float) -> list:
    """`accepted` with channel ch's bond replaced by a first-order one-pole fc, gain (the amplifier's noise
    after it, as the disc's bond: noise not filtered, not scaled by the gain)."""
    keep = [c for c in accepted if not (c.sensor == ch and c.effect in ("channel_lowpass", "sensor_gain"))]
    common = dict(score=0.0, p_value=0.0, material=True, significant=True, fold_params=[])
    return keep + [Candidate("channel_lowpass", ch, {"fc_hz": fc, "order": 1, "noise_filtered": False}, **common),
                   Candidate("sensor_gain", ch, {"gain": gain, "noise_kept": True}, **common)]


def prefiltered(session, ch: int, fc_hz: float, gain: float, f2_hz: float, f3_hz: float, order: int = 1):
    """The session with channel ch through the bond's inverse up to f2 (as the core's, on the whole record) and
    then `order` analogue one-poles at f3 (0: none), both bilinear (unwarped, as the core's inverse), rounded to
    counts: a prototype of a roll-off after the inverse (the amplifier noise the lift raises by f2 / (fc g) above
    f2, up to fs / 2, cut above the band the picks ride), fed to the core as a plain channel."""
    from scipy import signal as ss

    fs = float(session.rig.fs_hz)
    a = np.asarray(session.adc, float).copy()
    x = a[:, ch]
    x0 = x[:, :1].copy()
    b, den = ss.bilinear([1.0 / (2 * np.pi * fc_hz), 1.0], [gain / (2 * np.pi * f2_hz), gain], fs)
    y = ss.lfilter(b, den, x - x0, axis=-1)
    if f3_hz > 0.0:   # the analogue one-pole 1 / (1 + s / w3), bilinear as the inverse (a zero at fs / 2), `order` times
        bb, aa = ss.bilinear([1.0], [1.0 / (2 * np.pi * f3_hz), 1.0], fs)
        for _ in range(order):
            y = ss.lfilter(bb, aa, y, axis=-1)
    a[:, ch] = y + x0
    return dataclasses.replace(session, adc=np.clip(np.floor(a + 0.5), 0, session.rig.adc_max).astype(session.adc.dtype))


def _weighted_fit(toa, sx, sy, v, q, huber, sigma, start, plate):
    """(x, y): the Huber fit of toa_k = t0 + |p - s_k|_Q / v with residual k over sigma_k, from start."""
    from scipy.optimize import least_squares

    def res(p):
        dx, dy = p[0] - sx, p[1] - sy
        d = np.sqrt(np.maximum(q[0] * dx * dx + 2 * q[1] * dx * dy + q[2] * dy * dy, 1e-12))
        return (toa - p[2] - d / v) / sigma

    dx, dy = start[0] - sx, start[1] - sy
    t0 = float(np.mean(toa - np.sqrt(q[0] * dx * dx + 2 * q[1] * dx * dy + q[2] * dy * dy) / v))
    x0 = [min(max(start[0], 1e-3), plate[0] - 1e-3), min(max(start[1], 1e-3), plate[1] - 1e-3), t0]
    return least_squares(res, x0, loss="huber", f_scale=huber, method="trf",
                         bounds=([0.0, 0.0, -np.inf], [plate[0], plate[1], np.inf])).x[:2]


def weighted_phys(feats, cfg, sigma):
    """feats with the physics position (phys_xy_mm and the vector's phys_x_mm / phys_y_mm) moved by the
    difference between the picks' fit weighted by 1 / sigma^2 per channel and the unweighted one (the threshold
    picks; with band picks on, half that and half the band picks' difference: the core's mean of the two)."""
    from impactsense.pipeline import FEATURE_NAMES

    loc = cfg.localiser()
    sx, sy = np.asarray(loc.sensor_x_mm, float), np.asarray(loc.sensor_y_mm, float)
    sig = np.asarray(sigma, float)
    plate = (float(loc.plate_x_mm), float(loc.plate_y_mm))
    sets = [(np.asarray(feats.toa_us, float), float(loc.velocity_mm_per_us),
             (loc.travel_metric_xx, loc.travel_metric_xy, loc.travel_metric_yy))]
    if float(loc.band_velocity_mm_per_us) > 0:
        sets.append((np.asarray(feats.raw["toa_band_us"], float) - np.asarray(loc.band_delay_us, float)[None],
                     float(loc.band_velocity_mm_per_us), (loc.band_metric_xx, loc.band_metric_xy, loc.band_metric_yy)))
    phys = np.asarray(feats.phys_xy_mm, float)
    delta = np.zeros_like(phys)
    for toa, v, q in sets:
        for i in range(len(phys)):
            if not (np.isfinite(toa[i]).all() and np.isfinite(phys[i]).all()):
                continue
            p1 = _weighted_fit(toa[i], sx, sy, v, q, float(loc.huber_us), np.ones(4), phys[i], plate)
            pw = _weighted_fit(toa[i], sx, sy, v, q, float(loc.huber_us), sig, phys[i], plate)
            delta[i] += (pw - p1) / len(sets)
    out = dataclasses.replace(feats)
    out.phys_xy_mm = (phys + delta).astype(feats.phys_xy_mm.dtype)
    vec = np.array(feats.vector, copy=True)
    for k, name in enumerate(("phys_x_mm", "phys_y_mm")):
        vec[:, FEATURE_NAMES.index(name)] += delta[:, k]
    out.vector = vec
    return out


def with_three_delta(feats, cfg, ch):
    """feats with raw["three_delta"]: the threshold picks' Huber fit without channel ch less the fit with all four
    (mm; 0 where not placed): the three-sensor position beside the four-sensor one, a prototype input for the
    position forests (variant t3)."""
    loc = cfg.localiser()
    sx, sy = np.asarray(loc.sensor_x_mm, float), np.asarray(loc.sensor_y_mm, float)
    plate = (float(loc.plate_x_mm), float(loc.plate_y_mm))
    q = (loc.travel_metric_xx, loc.travel_metric_xy, loc.travel_metric_yy)
    toa, phys = np.asarray(feats.toa_us, float), np.asarray(feats.phys_xy_mm, float)
    sig = np.array([1e4 if k == ch else 1.0 for k in range(4)])
    delta = np.zeros_like(phys)
    for i in range(len(phys)):
        if np.isfinite(toa[i]).all() and np.isfinite(phys[i]).all():
            p4 = _weighted_fit(toa[i], sx, sy, float(loc.velocity_mm_per_us), q, float(loc.huber_us), np.ones(4), phys[i], plate)
            p3 = _weighted_fit(toa[i], sx, sy, float(loc.velocity_mm_per_us), q, float(loc.huber_us), sig, phys[i], plate)
            delta[i] = p3 - p4
    feats.raw["three_delta"] = delta
    return feats


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sessions")
    ap.add_argument("--name", default="bond")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--trees", type=int, default=30)
    ap.add_argument("--variants", default="base")
    ap.add_argument("--unchanged", type=float, default=float("nan"),
                    help="the unchanged sessions' mean MAE (default: measured, the reference model on same-1..3)")
    ap.add_argument("--forest-seed", type=int, default=-1, help="the forests' seed (default: --seed's)")
    ap.add_argument("--cache", default="", help="a scratch file keeping diagnose's and fit_bond's result")
    args = ap.parse_args()
    warnings.filterwarnings("ignore", message=".*sklearn.utils.parallel.delayed.*")
    folder = Path(args.sessions)
    truth = json.loads((folder / "manifest.json").read_text())["sessions"][args.name]["truth"]["params"]
    t0 = time.time()
    cache_file = Path(args.cache) if args.cache else None
    if cache_file is not None and cache_file.exists():   # a run's own scratch (pickle: never a user's folder)
        det_ref, accepted, ch = pickle.loads(cache_file.read_bytes())
        det = {"ref": det_ref}
        ref, sess = load_session(folder / "ref"), load_session(folder / args.name)
    else:
        ref, sess, det, accepted, ch = sized_bond(args.sessions, args.name, args.seed)
        if cache_file is not None:
            cache_file.write_bytes(pickle.dumps((det["ref"], accepted, ch)))
    lp = next(c.params for c in accepted if c.effect == "channel_lowpass" and c.sensor == ch)
    g = next(c.params["gain"] for c in accepted if c.effect == "sensor_gain" and c.sensor == ch)
    print(f"{folder.name}/{args.name}: channel {ch}; truth {truth['fc_hz']:.0f} Hz x{truth['gain']:.3f}; fit_bond "
          f"order {lp.get('order', 2)} {lp['fc_hz']:.0f} Hz x{g:.3f} ({time.time() - t0:.0f} s)", flush=True)
    forest_seed = args.seed if args.forest_seed < 0 else args.forest_seed
    settings = ForestSettings(n_estimators=args.trees, seed=forest_seed)
    unchanged = args.unchanged
    if not np.isfinite(unchanged):   # the reference model with the same forests' seed on same-1..3
        ref_model, _ = train(ref, None, 0.0, args.seed, None, settings=settings, site_map=None)
        unchanged = float(np.mean([score(load_session(folder / f"same-{k}"), ref_model)["mae_mm"]
                                   for k in (1, 2, 3)]))
    base_limit = bond_inverse.BOND_LIMIT_OF_PICK
    with tempfile.TemporaryDirectory() as tmp:
        cache = {}

        def training(effects, tag):
            if tag not in cache:
                draws = loop.training_draws
                if tag.startswith("d"):
                    loop.training_draws = lambda _accepted, n=int(tag[1:]): n
                try:
                    cache[tag] = measured_training_session(ref, effects, det["ref"], Path(tmp) / tag, args.seed)
                finally:
                    loop.training_draws = draws
            return cache[tag]

        own_rms = {}
        import impactsense.models as _models
        import impactsense.workflow as _workflow
        plain_featurize = _workflow.featurize
        plain_location_matrix = _models.location_matrix
        for var in args.variants.split(","):
            t1 = time.time()
            _workflow.featurize = _models.featurize = plain_featurize
            _models.location_matrix = plain_location_matrix
            bond_inverse.BOND_LIMIT_OF_PICK = base_limit
            effects, tag, inv = accepted, "fit", None
            if var.startswith("k"):
                bond_inverse.BOND_LIMIT_OF_PICK = float(var[1:])
            elif var.startswith("f"):   # fX: the core's onset_noise_factor X (the picks' threshold refitted on it)
                inv = ("factor", float(var[1:]))
            elif var == "truth":
                effects, tag = with_bond(accepted, ch, truth["fc_hz"], truth["gain"]), "truth"
            elif var.startswith("d"):   # dN: N copies of each training drop, each its own draw of the bond's noise
                effects, tag = accepted, var
            elif var.startswith("g"):
                inv = ("gain", float(var[1:]))
            elif var == "truthinv":
                inv = (truth["fc_hz"], truth["gain"])
            elif var == "spectral":
                fc_s, g_s = spectral_one_pole(ref, sess, ch)
                print(f"  spectral one-pole {fc_s:.0f} Hz x{g_s:.3f}")
                effects, tag = with_bond(accepted, ch, fc_s, g_s), "spectral"
            elif var.startswith("w"):   # wX / wm: the bonded channel's pick weighted as X x as scattered
                scale = (own_rms["bonded"] / own_rms["others"]) if var == "wm" else float(var[1:])
                sigma = [scale if k == ch else 1.0 for k in range(4)]
                print(f"  {var}: the bonded channel's sigma x{scale:.2f}")

                def patched(adc, cfg, sigma=sigma):
                    return weighted_phys(plain_featurize(adc, cfg), cfg, sigma)
                _workflow.featurize = _models.featurize = patched
            elif var == "z":   # the bonded channel's onset columns held constant in the position forests' inputs
                def patched_matrix(features, names):
                    from impactsense.pipeline import onset_columns
                    m = np.array(plain_location_matrix(features, names), copy=True)
                    drop = set(onset_columns(ch, names))
                    m[:, [k for k, n in enumerate(names) if n in drop]] = 0.0
                    return m
                _models.location_matrix = patched_matrix
            elif var == "t3":   # the three-sensor fit's offset as two more position-forest inputs
                def patched(adc, cfg):
                    return with_three_delta(plain_featurize(adc, cfg), cfg, ch)

                def patched_matrix(features, names):
                    return np.concatenate([plain_location_matrix(features, names),
                                           np.asarray(features.raw["three_delta"], np.float32)], 1)
                _workflow.featurize = _models.featurize = patched
                _models.location_matrix = patched_matrix
            elif var.startswith("p"):   # pX[oN]: the inverse as a prefilter, then N one-poles at X x the pick frequency
                x_of_pick, _, order = var[1:].partition("o")
                inv = ("pre", float(x_of_pick), int(order or 1))
            elif var != "base":
                raise SystemExit(f"unknown variant {var}")
            train_s = training(effects, tag)
            signal = pick_settings(train_s, effects, ref)
            sess_v = sess
            if inv is not None and inv[0] == "pre":
                signal = dataclasses.replace(signal)
                fc, g2, f2 = (list(v)[ch] for v in (signal.bond_corner_hz, signal.bond_gain, signal.bond_limit_hz))
                f3 = inv[1] * f2 / bond_inverse.BOND_LIMIT_OF_PICK
                signal.bond_corner_hz, signal.bond_gain, signal.bond_limit_hz = [0.0] * 4, [1.0] * 4, [0.0] * 4
                train_s = prefiltered(train_s, ch, fc, g2, f2, f3, inv[2])
                sess_v = prefiltered(sess, ch, fc, g2, f2, f3, inv[2])
            elif inv is not None and inv[0] == "factor":
                signal = dataclasses.replace(signal, onset_noise_factor=inv[1])
            elif inv is not None and inv[0] == "gain":
                signal = dataclasses.replace(signal)
                signal.channel_gain = [inv[1] if k == ch else v for k, v in enumerate(signal.channel_gain)]
            elif inv is not None and signal is not None:
                signal = dataclasses.replace(signal)
                signal.bond_corner_hz = [inv[0] if k == ch else v for k, v in enumerate(signal.bond_corner_hz)]
                signal.bond_gain = [inv[1] if k == ch else v for k, v in enumerate(signal.bond_gain)]
            model, _ = carry_delays(train(train_s, None, 0.0, args.seed, None, settings=settings, signal=signal,
                                          site_map=None), channel_delays(effects))
            mae = score(sess_v, model)["mae_mm"]
            res = lag_residual(train_s, sess_v, model.signal)
            own = lag_residual(train_s, train_s, model.signal)
            if var == "base":
                own_rms = {"bonded": own[ch][1], "others": float(np.median([r for k, (_, r) in enumerate(own) if k != ch]))}
            if sess_v is sess:
                f2 = list(model.signal.bond_limit_hz)[ch]
                fc = list(model.signal.bond_corner_hz)[ch]
            roll = f", roll-off {f3:.0f} Hz x{inv[2]}" if sess_v is not sess else ""
            ms = model.signal
            print(f"  {var}: inverse fc {fc:.0f} f2 {f2:.0f} Hz{roll}; picks: noise factor {float(ms.onset_noise_factor):.1f}, "
                  f"threshold {float(ms.onset_threshold_counts):.0f}, blend {float(ms.aic_blend):.2f}; MAE {mae:.2f} mm ({mae / unchanged:.3f} x unchanged "
                  f"{unchanged:.2f}); lag less the training cubic, mean/rms us: "
                  + ", ".join(f"ch{k}{'*' if k == ch else ''} {m:+.1f}/{r:.1f}" for k, (m, r) in enumerate(res))
                  + "; the training drops' own rms: " + ", ".join(f"{r:.1f}" for _, r in own)
                  + f" ({time.time() - t1:.0f} s)", flush=True)
        _workflow.featurize = _models.featurize = plain_featurize
        _models.location_matrix = plain_location_matrix
    bond_inverse.BOND_LIMIT_OF_PICK = base_limit
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
