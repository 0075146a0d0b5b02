"""Which picks a model retrained for a raised white-noise floor should be trained with (a study for issue 16, no
target): a measured training session (bench_loop's OUT/<name>-measured: the reference drops with the diagnosed
noise put in, several draws, and the twin's drops) trained as bench_loop trains it, once per fixed pick setting
with the onset threshold's choice off, and scored on the noisy session and on unchanged sessions with another draw
of the same white noise (benchmarks/loop_sessions.py's signal model).

    python3 benchmarks/bench_noise_training.py TRAINING SESSION [CONTROL ...] [--white 9.77]
        [--picks 50:0.2,50:0] [--noise-factor 3] [--trees 30] [--seed 5] [--reference REF]

--picks: onset_threshold_counts:aic_blend pairs, each trained with `travel.choose_threshold` held to it (the pair
is what the core picks with; the threshold is still max(it, --noise-factor x the channel's noise rms)); "choose"
trains with the choice on (what `retrain` does). --reference REF: the band picks' floor is REF's drops' noise (the
session without the change), as `loop.pick_settings` sets it under a diagnosed noise; without it the training
drops' own noise (the floor before Session 23). Prints per pair the chosen core settings, the whole-plate MAE
(physics MAE) on SESSION and the MAE on each CONTROL with the noise put in.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path
from unittest import mock

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_loop  # noqa: E402
import bench_noise_picks  # noqa: E402


def noisy(session, white: float, seed: int):
    truth = {"effect": "noise", "sensor": None, "params": {"noise_counts_rms": white}}
    return dataclasses.replace(session, adc=bench_noise_picks.changed_adc(session, truth, seed))


def trained(training, pair: str, noise_factor: float, trees: int, seed: int, reference=None):
    """The model trained on `training` with the pick pair held ("thr:blend") or chosen ("choose"); with
    `reference` the band picks' floor is its drops' noise (pipeline.training_noise_floor)."""
    import numpy as np

    import impactsense.travel as travel
    from impactsense.pipeline import training_noise_floor
    from impactsense.signal import SignalConfig

    def floored(cfg):
        if reference is not None:
            cfg.band_noise_counts = training_noise_floor(reference, np.arange(len(reference)), cfg)
        return cfg

    if pair == "choose":
        cfg = floored(SignalConfig.for_rig(training.rig, onset_noise_factor=noise_factor))
        return bench_loop.train_score(training, trees, seed, cfg)[0]
    thr, blend = (float(v) for v in pair.split(":"))
    cfg = floored(SignalConfig.for_rig(training.rig, onset_threshold_counts=thr, aic_blend=blend,
                                       onset_noise_factor=noise_factor))
    with mock.patch.object(travel, "THRESHOLD_FACTORS", (1.0,)), mock.patch.object(travel, "AIC_BLENDS", ()):
        return bench_loop.train_score(training, trees, seed, cfg)[0]


def main(argv=None) -> int:
    from impactsense.commands.retrain import score
    from impactsense.data import load_session

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("training")
    ap.add_argument("session")
    ap.add_argument("controls", nargs="*")
    ap.add_argument("--white", type=float, default=9.77, help="white noise put into the controls (counts rms)")
    ap.add_argument("--picks", default="choose,50:0.2,50:0")
    ap.add_argument("--noise-factor", type=float, default=3.0)
    ap.add_argument("--trees", type=int, default=30)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--reference", help="session whose drops' noise is the band picks' floor (default: the "
                    "training drops')")
    args = ap.parse_args(argv)
    training, session = load_session(args.training), load_session(args.session)
    controls = [noisy(load_session(p), args.white, 2000 + i) for i, p in enumerate(args.controls)]
    for pair in args.picks.split(","):
        t0 = time.time()
        model = trained(training, pair, args.noise_factor, args.trees, args.seed,
                        load_session(args.reference) if args.reference else None)
        s = score(session, model)
        got = ", ".join(f"{k} {getattr(model.signal, k):g}" for k in ("onset_threshold_counts", "aic_blend",
                                                                        "band_pick_hz", "band_noise_counts"))
        ctl = " / ".join(f"{score(c, model)['mae_mm']:.2f}" for c in controls)
        print(f"{pair:>8} ({got}): session {s['mae_mm']:.2f} mm (physics {s['physics_mae_mm']:.2f}); controls + "
              f"{args.white:g} counts: {ctl or '-'} ({time.time() - t0:.0f} s)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
