"""A measured-trained model with the onset threshold and AIC blend forced (what the trainer's choice is worth).

    python3 benchmarks/bench_threshold_forced.py DATA --seed S --pick 30/0 [--trees 100]

`train` + `evaluate` as bench_rigs.py scores a rig (held-out 20 % of cases, split seed S, no calibration), with
travel.choose_threshold replaced by the given threshold (counts) / AIC blend: the travel law is fitted on those
picks and every later choice (band picks, starts, members, forests) is the trainer's own. Prints the held-out
MAE per axis, the class accuracy and the physics MAE. --pick auto: the trainer's own choice (main's figure).
docs/findings.md "Session 28: rigcmt2" reads it (rig-c seed 0: its choice 50/0.2 against 30/0 and 20/0).
"""

from __future__ import annotations

import argparse
import time
import warnings


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--pick", default="auto", help="THRESHOLD/BLEND, or auto")
    ap.add_argument("--trees", type=int, default=100)
    args = ap.parse_args()
    warnings.filterwarnings("ignore", category=UserWarning)
    import impactsense.travel as travel
    from impactsense.data import load_session
    from impactsense.models import ForestSettings
    from impactsense.sitemap import resolve_site_map
    from impactsense.workflow import evaluate, train

    if args.pick != "auto":
        thr, blend = (float(v) for v in args.pick.split("/"))

        def forced(adc, xy, cfg, anisotropic, rig_drops=None):
            toa, period = travel.picks(adc, cfg, with_period=True, onset_threshold_counts=thr, aic_blend=blend)
            fit = travel.fit_travel(toa, xy, cfg.sensor_xy_mm, anisotropic, period, cfg.fs_hz,
                                    left_out=cfg.channel_left_out)
            return thr, blend, fit, []

        travel.choose_threshold = forced     # pipeline.fit_localiser imports it at call time
    session = load_session(args.data)
    t = time.time()
    model, _ = train(session, None, 0.2, args.seed, None, ForestSettings(n_estimators=args.trees, seed=args.seed),
                     site_map=resolve_site_map("auto", session.rig), choose_twin=False, choose_class=True)
    rep = evaluate(session, model)
    sig = model.signal
    print(f"{session.name} seed {args.seed}, threshold {sig.onset_threshold_counts:g} / blend {sig.aic_blend:g} "
          f"({args.pick}): MAE {rep['all']['mae_mm']:.2f} mm, class {rep['energy_class_accuracy']:.3f}, physics "
          f"{rep['physics']['all']['mae_mm']:.2f} ({time.time() - t:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
