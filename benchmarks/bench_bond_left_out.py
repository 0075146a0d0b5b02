"""A bond the effects' signal model may not absorb: retrain's four-channel model against one trained with the
bond's channel left out (the core's channel_left_out during training: three-sensor picks, travel fit and forests).

On a loop session folder (benchmarks/loop_sessions.py: REF "ref" and the changed session, default "bond"): diagnose,
the bond's low-pass and gain sized on the recordings (loop.fit_bond), the effects put into the reference's
recordings (loop.measured_training_session), the core told the channel's gain (loop.pick_settings), as
`impactsense retrain` and bench_loop do. Prints the changed session's MAE (its own labels) of the model trained
on four channels and of the one trained with the channel left out, and a label-free candidate for the choice: the
held-out MAE of both on the training session's own case split (TEST_FRACTION), with the reference's (four
channels) beside it; on the drops every way places, the four-channel model's own three-sensor path (the channel
left out at prediction only) and the mean of the four-channel position with the left-out model's and with it. No target: a measurement (docs/findings.md "Training with a channel left out").

The channel check (channel_check.py) of the changed session: its bond channel's median score against a check fitted
on the reference's drops (the four-channel model's signal), against a baseline model's (the reference's default
split, as retrain trains it) and against the four-channel model's own (fitted on the training drops with the bond's
effects in), the share of drops each flags, and the four-channel MAE with its check off.

    python benchmarks/bench_bond_left_out.py SESSIONS [--name bond] [--seed N] [--trees 60] [--no-held-out]
"""

from __future__ import annotations

import argparse
import copy
import tempfile
from pathlib import Path

import numpy as np

from impactsense.channel_check import channel_scores, fit_channel_check, flagged_channel
from impactsense.commands.retrain import leave_out, score
from impactsense.loop import measured_training_session, pick_settings
from impactsense.models import ForestSettings
from impactsense.pipeline import featurize
from impactsense.workflow import train

from benchlib import sized_bond

TEST_FRACTION = 0.3


def held_out_mae(session, signal, settings, seed: int) -> float:
    """MAE per axis on the session's held-out cases of a model trained on the rest."""
    model, split = train(session, None, TEST_FRACTION, seed, None, settings=settings, signal=signal, site_map=None)
    rows = np.flatnonzero(np.isin(session.recording_id, split["test_recordings"]))
    out = model.predict(featurize(session.adc[rows], model.signal))
    return float(np.nanmean(np.abs(out["xy_mm"] - session.xy_mm[rows])))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sessions")
    ap.add_argument("--name", default="bond")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--trees", type=int, default=60)
    ap.add_argument("--no-held-out", action="store_true", help="skip the training drops' held-out candidates")
    args = ap.parse_args()
    ref, sess, det, accepted, channel = sized_bond(args.sessions, args.name, args.seed)
    if channel < 0:
        return 0
    settings = ForestSettings(n_estimators=args.trees, seed=args.seed)
    with tempfile.TemporaryDirectory() as tmp:
        training = measured_training_session(ref, accepted, det["ref"], Path(tmp) / "training", args.seed)
        four = pick_settings(training, accepted)
        three = leave_out(four, [channel])
        mae, models = {}, {}
        for tag, signal in (("four", four), ("three", three)):
            models[tag], _ = train(training, None, 0.0, args.seed, None, settings=settings, signal=signal,
                                   site_map=None)
            mae[tag] = score(sess, models[tag])["mae_mm"]
        both = mean_of_both(sess, models["four"], models["three"], channel)
        check = channel_check_figures(ref, sess, models["four"], channel, args.seed)
        oof = None if args.no_held_out else {"reference": held_out_mae(ref, None, settings, args.seed),
                                             "four": held_out_mae(training, four, settings, args.seed),
                                             "three": held_out_mae(training, three, settings, args.seed)}
    print(f"{args.name}: channel {channel} ({', '.join(f'{c.effect} {c.params}' for c in accepted)})")
    print(f"  on the changed session: four channels {mae['four']:.2f} mm (without the channel check "
          f"{check['four_unchecked_mm']:.2f}), channel {channel} left out {mae['three']:.2f} mm")
    print(f"  on the {both['n']} drops every way places: four {both['four']:.2f}, trained without the channel "
          f"{both['three']:.2f}, the four-channel model's three-sensor path {both['fallback']:.2f}; mean of four and "
          f"trained-without {both['mean']:.2f}, of four and its three-sensor path {both['mean_fallback']:.2f}; the "
          f"four-channel model's drops flagged {both['flagged']:.2f}")
    print(f"  channel check, channel {channel}'s median score: against the reference's drops "
          f"{check['reference_score']:.2f} (flagged {check['reference_flagged']:.2f}), against a baseline model's "
          f"{check['baseline_score']:.2f} (flagged {check['baseline_flagged']:.2f}), against retrain's four-channel "
          f"model's {check['four_score']:.2f} (flagged {check['four_flagged']:.2f}); the other channels' largest "
          f"median "
          f"{check['others_score']:.2f}")
    if oof is not None:
        print(f"  training drops held out: reference {oof['reference']:.2f}, four {oof['four']:.2f} "
              f"({oof['four'] / oof['reference']:.2f} x), three {oof['three']:.2f} ({oof['three'] / oof['four']:.2f} x four)")
    return 0


def mean_of_both(sess, four_model, three_model, channel: int) -> dict:
    """MAE per axis (mm) on the changed session's drops every way places: the four-channel model, the model
    trained with the channel left out, the four-channel model told to leave it out at prediction (its
    three-sensor path), and the means of the four-channel position with each; the share of drops the
    four-channel model's report flags (bad_channel)."""
    p4 = four_model.predict(four_model.featurize(sess.adc))
    fallback = copy.copy(four_model)
    fallback.signal = leave_out(four_model.signal, [channel])
    pf = fallback.predict(fallback.featurize(sess.adc))["xy_mm"]
    p3 = three_model.predict(three_model.featurize(sess.adc))["xy_mm"]
    xy4 = p4["xy_mm"]
    ok = np.all(np.isfinite(xy4) & np.isfinite(p3) & np.isfinite(pf), axis=1)
    mae = {tag: float(np.mean(np.abs(xy[ok] - sess.xy_mm[ok])))
           for tag, xy in (("four", xy4), ("three", p3), ("fallback", pf), ("mean", 0.5 * (xy4 + p3)),
                           ("mean_fallback", 0.5 * (xy4 + pf)))}
    mae["n"] = int(ok.sum())
    mae["flagged"] = float(np.mean(np.asarray(p4.get("bad_channel", np.full(len(sess), -1))) >= 0))
    return mae


def channel_check_figures(ref, sess, four_model, channel: int, seed: int) -> dict:
    """The channel check's view of the bond (channel_check.py): the median score of its channel on the changed
    session against a check fitted on the reference's drops (the four-channel model's signal), against the check
    of a model of the reference as retrain's baseline is trained (default split, its own localiser fit) and against
    the retrained four-channel model's own check, the shares of drops flagged on it, and that model's MAE on the
    changed session with its check off."""
    ref_feats = featurize(ref.adc, four_model.signal)
    ref_check = fit_channel_check(ref_feats.raw, four_model.signal, ref_feats.phys_xy_mm, ref.xy_mm)
    # what retrain itself holds: its baseline model (DATA_REF's default split, its own localiser fit) and its check
    baseline, _ = train(ref, None, 0.2, seed, None, settings=ForestSettings(n_estimators=5, seed=seed), site_map=None)
    out = {}
    for tag, check, signal in (("reference", ref_check, four_model.signal),
                               ("baseline", baseline.card["channel_check"], baseline.signal),
                               ("four", four_model.card["channel_check"], four_model.signal)):
        feats = featurize(sess.adc, signal)
        scores = channel_scores(feats.raw, signal, check, feats.phys_xy_mm)
        with np.errstate(all="ignore"):
            med = np.nanmedian(scores, axis=0)
        out[f"{tag}_score"] = float(med[channel])
        out[f"{tag}_flagged"] = float(np.mean(flagged_channel(scores, check) == channel))
        if tag == "four":
            out["others_score"] = float(np.nanmax(np.delete(med, channel)))
    unchecked = copy.copy(four_model)
    unchecked.card = {k: v for k, v in four_model.card.items() if k != "channel_check"}
    out["four_unchecked_mm"] = score(sess, unchecked)["mae_mm"]
    return out


if __name__ == "__main__":
    raise SystemExit(main())
