"""What a bonded channel leaves to any retrain: the bond's shape, the signal-to-noise it takes, its pick delay and
scatter, and the MAE of retrain's model against the oracle's (a model trained on the reference's own drops
recorded with the session's true bond) and the session's own training split.

On a loop session folder made with `benchmarks/loop_sessions.py --controls --oracles --only ref,same-1,same-2,
same-3,bond` (REF "ref", the bond session, `<name>-control`: its drops without the bond, `<name>-oracle`: the
reference's drops with it): diagnose, the bond sized on the recordings (loop.fit_bond), as `impactsense retrain`.
Printed:

- shape: the measured transfer of the bond channel (the changed session's spectrum against its control's, the
  same drops) and its least-squares one-pole; |H| at a few frequencies for it, the truth, diagnose's low-pass and
  fit_bond's; the other channels' pick frequency (fs / pick_period);
- the signal-to-noise ratio in the first PICK_WINDOW samples after each drop's onset (the control's pick),
  by frequency, on the control and on the changed session (the amplifier's noise comes after the bond: what the
  bond takes is not given back by any filter of the recordings);
- the bond channel's pick delay per drop (its onset less the travel time less the other channels' mean, the
  changed session's less the control's on the same drops): median, scatter, correlation with the distance to
  the disc and the drop height; retrain's training data's delay (against the reference's drops) about a cubic in
  position and the session's delay less that cubic (a bias the training data does not carry, and the rest);
- MAE per axis (mm): the reference model on same-1..3 (those present) and on the control; retrain's four-channel
  model (fit_bond's effects in the reference's drops, loop.pick_settings) and the oracle's (the same settings) on
  the bond session; a 2-fold split by case of the bond session and of its control (each half placed by a model of
  the other half), their ratio;
- the same four-channel model with the bond channel of its training drops and of the session passed through the
  inverse of fit_bond's one-pole, limited above INVERSE_AT x its corner ((1 + j f / fc) / (g (1 + j f / f2)),
  bilinear; the rig's picks, no channel gain): would an inverse before picking give the channel back (a prototype
  on the recordings; the core has no such filter).

No target: a measurement (docs/findings.md "Session 24: bond5").

    python benchmarks/bench_bond_floor.py SESSIONS [--name bond] [--seed N] [--trees 30]
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from impactsense.commands.retrain import carry_delays, score
from impactsense.data import load_session
from impactsense.effects.channel_lowpass import lowpass_gain_at
from impactsense.loop import channel_delays, measured_training_session, pick_settings
from impactsense.models import ForestSettings
from impactsense.pipeline import featurize, fit_localiser
from impactsense.signal import SignalConfig
from impactsense.workflow import train

from bench_bond_picks import cubic, pick_lag
from benchlib import sized_bond

PRETRIGGER = 64
PICK_WINDOW = 64
FREQS_KHZ = (1, 2, 3, 5, 8, 10, 15, 20, 30)
INVERSE_AT = (2.0, 3.0, 4.0)


def inverse_bond(session, ch: int, fc_hz: float, gain: float, f2_hz: float):
    """The session with channel ch through the one-pole's inverse up to f2: (1 + s / wc) / (g (1 + s / w2))."""
    import dataclasses

    from scipy import signal as ss

    fs = float(session.rig.fs_hz)
    a = np.asarray(session.adc, float).copy()
    x = a[:, ch] - float(session.rig.bias_counts)
    b, den = ss.bilinear([1.0 / (2 * np.pi * fc_hz), 1.0], [gain / (2 * np.pi * f2_hz), gain], fs)
    a[:, ch] = ss.lfilter(b, den, x - x[:, :1], axis=-1) + x[:, :1] + float(session.rig.bias_counts)
    return dataclasses.replace(session, adc=np.clip(np.rint(a), 0, session.rig.adc_max).astype(session.adc.dtype))


def one_pole(f, fc_hz: float, gain: float):
    return gain / (1.0 + 1j * np.asarray(f, float) / fc_hz)


def measured_transfer(changed, control, ch: int) -> tuple[np.ndarray, np.ndarray, float, float]:
    """(f, H(f), fc, gain): the channel's cross-spectral transfer from the control's drops to the changed
    session's (the same drops), and its one-pole least-squares fit weighted by the control's power in 0.5-30 kHz."""
    fs = float(changed.rig.fs_hz)
    b = np.asarray(changed.adc[:, ch], float)
    c = np.asarray(control.adc[:, ch], float)
    b -= b[:, :PRETRIGGER].mean(1, keepdims=True)
    c -= c[:, :PRETRIGGER].mean(1, keepdims=True)
    f = np.fft.rfftfreq(b.shape[1], 1.0 / fs)
    fb, fc_ = np.fft.rfft(b), np.fft.rfft(c)
    w = (np.abs(fc_) ** 2).sum(0)
    h = (fb * fc_.conj()).sum(0) / w
    band = (f > 500.0) & (f < 30000.0)
    sw = np.sqrt(w[band] / w[band].sum())

    def resid(p):
        return (sw * (h[band] - one_pole(f[band], p[0], p[1]))).view(float)

    fit = least_squares(resid, [3000.0, 0.7], bounds=([100.0, 0.0], [0.45 * fs, 2.0]))
    return f, h, float(fit.x[0]), float(fit.x[1])


def onset_snr_db(session, ch: int, onset_sample: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(f, SNR dB): the channel's mean power in PICK_WINDOW samples from each drop's onset over the same in its
    first PICK_WINDOW (pre-trigger) samples."""
    x = np.asarray(session.adc[:, ch], float)
    n = PICK_WINDOW
    sig = np.stack([x[k, i:i + n] for k, i in enumerate(onset_sample)])
    noise = x[:, :n]
    p = lambda z: (np.abs(np.fft.rfft(z - z.mean(1, keepdims=True))) ** 2).mean(0)   # noqa: E731
    with np.errstate(divide="ignore", invalid="ignore"):   # the mean taken out: the 0 Hz bin is 0 / 0
        return np.fft.rfftfreq(n, 1.0 / float(session.rig.fs_hz)), 10.0 * np.log10(p(sig) / p(noise))


def within_case_sd(session, v: np.ndarray) -> float:
    ok = np.isfinite(v)
    var = [np.var(v[(session.case_id == c) & ok], ddof=1) for c in np.unique(session.case_id)
           if ((session.case_id == c) & ok).sum() > 1]
    return float(np.sqrt(np.mean(var)))


def split_mae(session, signal, trees: int, seed: int) -> float:
    """MAE per axis of a 2-fold split by case (each half placed by a model trained on the other half)."""
    cases = np.unique(session.case_id)
    np.random.default_rng(seed).shuffle(cases)
    errs = []
    for k in range(2):
        test = np.isin(session.case_id, cases[k::2])
        model, _ = train(session.subset(np.flatnonzero(~test)), None, 0.0, seed, None,
                         settings=ForestSettings(n_estimators=trees, seed=seed), signal=signal, site_map=None)
        part = session.subset(np.flatnonzero(test))
        errs.append(np.abs(model.predict(model.featurize(part.adc))["xy_mm"] - part.xy_mm))
    return float(np.nanmean(np.concatenate(errs)))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sessions")
    ap.add_argument("--name", default="bond")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--trees", type=int, default=30)
    args = ap.parse_args()
    folder = Path(args.sessions)
    for need in ("ref", args.name, f"{args.name}-control", f"{args.name}-oracle"):
        if not (folder / need / "recordings.npz").exists():
            raise SystemExit(f"{folder / need}: missing; make it with benchmarks/loop_sessions.py --controls "
                             f"--oracles --only ref,{args.name}")
    truth = json.loads((folder / "manifest.json").read_text())["sessions"][args.name]["truth"]
    ref, sess, det, accepted, ch = sized_bond(args.sessions, args.name, args.seed)
    if ch < 0:
        return 0
    control, oracle = load_session(folder / f"{args.name}-control"), load_session(folder / f"{args.name}-oracle")
    fs = float(ref.rig.fs_hz)
    tp = truth["params"]
    lp_d = next(c.params for c in det["accepted"] if c.effect == "channel_lowpass" and c.sensor == ch)
    g_d = next((c.params["gain"] for c in det["accepted"] if c.effect == "sensor_gain" and c.sensor == ch), 1.0)
    lp_f = next((c.params for c in accepted if c.effect == "channel_lowpass" and c.sensor == ch), None)
    g_f = next(c.params["gain"] for c in accepted if c.effect == "sensor_gain" and c.sensor == ch)

    # shape
    f, h, fc_m, g_m = measured_transfer(sess, control, ch)
    cfg = SignalConfig.for_rig(ref.rig)
    period = np.asarray(featurize(control.adc, cfg).raw["pick_period"], float)
    f_pick = fs / np.nanmedian(period, axis=0)
    print(f"{args.name}: channel {ch}; truth one-pole {tp['fc_hz']:.0f} Hz x{tp['gain']:.3f}; measured one-pole "
          f"{fc_m:.0f} Hz x{g_m:.3f}; diagnose order {lp_d.get('order', 2)} {lp_d['fc_hz']:.0f} Hz x{g_d:.3f}; "
          f"fit_bond " + (f"order {lp_f.get('order', 2)} {lp_f['fc_hz']:.0f} Hz x{g_f:.3f}" if lp_f else
                          f"no low-pass, x{g_f:.3f}"))
    print(f"pick frequency per channel (control, kHz): {', '.join(f'{v / 1e3:.1f}' for v in f_pick)}")
    print("| f kHz | measured abs(H) | truth | diagnose | fit_bond |")
    print("|---|---|---|---|---|")
    for fk in FREQS_KHZ:
        i = int(np.argmin(np.abs(f - fk * 1e3)))
        hd = g_d * lowpass_gain_at(fk * 1e3, lp_d["fc_hz"], fs, lp_d.get("order", 2))
        hf = g_f * (lowpass_gain_at(fk * 1e3, lp_f["fc_hz"], fs, lp_f.get("order", 2)) if lp_f else 1.0)
        print(f"| {fk} | {abs(h[i]):.3f} | {abs(one_pole(fk * 1e3, tp['fc_hz'], tp['gain'])):.3f} | {hd:.3f} | "
              f"{hf:.3f} |")

    # signal-to-noise at the onset
    loc = fit_localiser(ref, np.arange(len(ref)), cfg)
    onset = np.rint(np.asarray(featurize(control.adc, loc).toa_us, float)[:, ch] * fs / 1e6).astype(int)
    fq, snr_c = onset_snr_db(control, ch, onset)
    _, snr_b = onset_snr_db(sess, ch, onset)
    print(f"\nSNR (dB) in {PICK_WINDOW} samples from the onset, channel {ch}: control / {args.name}")
    print(" | ".join(f"{fq[i] / 1e3:.0f} kHz {snr_c[i]:.1f} / {snr_b[i]:.1f}"
                     for i in range(1, len(fq)) if fq[i] <= 40e3 and i % 2 == 0))

    with tempfile.TemporaryDirectory() as tmp:
        training = measured_training_session(ref, accepted, det["ref"], Path(tmp) / "t", args.seed)
        signal = pick_settings(training, accepted, ref)
        picks = signal if signal is not None else loc
        gains = list(picks.channel_gain) if picks is not None else [1.0] * 4

        # pick delay per drop
        import dataclasses
        told = dataclasses.replace(loc, channel_gain=gains)
        d_sess = pick_lag(sess, told, ch) - pick_lag(control, loc, ch)
        ok = np.isfinite(d_sess)
        dist = np.linalg.norm(sess.xy_mm - np.asarray(loc.sensor_xy_mm, float)[ch], axis=1)
        print(f"\npick delay of channel {ch} (onset gain {gains[ch]:.3f}; {args.name} less control, same drops): "
              f"median {np.nanmedian(d_sess):.1f} us, sd {np.nanstd(d_sess):.1f}, within a case "
              f"{within_case_sd(sess, pick_lag(sess, told, ch)):.1f} (control {within_case_sd(control, pick_lag(control, loc, ch)):.1f}); "
              f"corr with distance {np.corrcoef(dist[ok], d_sess[ok])[0, 1]:+.2f}, height "
              f"{np.corrcoef(sess.height_mm[ok], d_sess[ok])[0, 1]:+.2f}")
        ref_lag = pick_lag(ref, loc, ch)
        for tag, s in (("training", training.subset(np.arange(len(ref)))), ("oracle", oracle)):
            d = pick_lag(s, told, ch) - ref_lag
            k = np.isfinite(d)
            coef = np.linalg.lstsq(cubic(ref.xy_mm[k], ref.rig), d[k], rcond=None)[0]
            e = (d_sess - cubic(sess.xy_mm, sess.rig) @ coef)[ok]
            print(f"  {tag}'s delay: median {np.nanmedian(d):.1f} us, about its cubic "
                  f"{np.std(d[k] - cubic(ref.xy_mm[k], ref.rig) @ coef):.1f}; the session's delay less that cubic: "
                  f"mean {e.mean():+.1f} us, rms {np.sqrt(np.mean(e ** 2)):.1f}")

        # MAE
        settings = ForestSettings(n_estimators=args.trees, seed=args.seed)

        def fitted(s, sig):
            model, _ = train(s, None, 0.0, args.seed, None, settings=settings, signal=sig, site_map=None)
            return model

        ref_model = fitted(ref, None)
        same = [score(load_session(folder / f"same-{k}"), ref_model)["mae_mm"] for k in (1, 2, 3)
                if (folder / f"same-{k}" / "recordings.npz").exists()]
        unchanged = float(np.mean(same)) if same else float("nan")
        ctrl = score(control, ref_model)["mae_mm"]
        four, _ = carry_delays((fitted(training, signal), None), channel_delays(accepted))
        four_mae = score(sess, four)["mae_mm"]
        orac_mae = score(sess, fitted(oracle, signal))["mae_mm"]
        own_b, own_c = split_mae(sess, signal, args.trees, args.seed), split_mae(control, None, args.trees, args.seed)
        inverse = {}
        if lp_f is not None and lp_f.get("order", 2) == 1:
            for mult in INVERSE_AT:
                f2 = min(mult * lp_f["fc_hz"], 0.4 * fs)
                m, _ = carry_delays((fitted(inverse_bond(training, ch, lp_f["fc_hz"], g_f, f2), cfg), None),
                                   channel_delays(accepted))
                inverse[f2] = score(inverse_bond(sess, ch, lp_f["fc_hz"], g_f, f2), m)["mae_mm"]
    print(f"\nMAE (mm, {args.trees} trees): reference on same-1..{len(same)} {unchanged:.2f}, on the control {ctrl:.2f}, "
          f"on {args.name} {score(sess, ref_model)['mae_mm']:.2f}")
    print(f"  retrain's four-channel model {four_mae:.2f} ({four_mae / unchanged:.2f} x unchanged, "
          f"{four_mae / ctrl:.2f} x control); the oracle {orac_mae:.2f} ({orac_mae / unchanged:.2f} x, "
          f"{orac_mae / ctrl:.2f} x control)")
    print(f"  own 2-fold split: {args.name} {own_b:.2f}, control {own_c:.2f} ({own_b / own_c:.2f} x)")
    for f2, mae in inverse.items():
        print(f"  fit_bond's inverse up to {f2:.0f} Hz before picking: {mae:.2f} ({mae / unchanged:.2f} x unchanged, "
              f"{mae / ctrl:.2f} x control)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
