"""How often the core reads the picked cycle's period, and what the travel fit makes of it, per session.

    python3 benchmarks/bench_pick_period.py DATA [DATA ...]

Per session (every drop, the rig's signal configuration, the rig's delays off as travel.picks reads them): the
fraction of channels whose `pick_period` is NaN (the zero crossings not found within impactcore.h kPeriodSearch),
the median period (samples) and frequency, the fraction of pick periods longer than 21 samples (what a 32-sample
search can read: 1.5 periods and the lead), and the travel fit at the drops' declared positions (travel.fit_travel,
the metric where the material wants it) without and with the periods: robust residual spread (us) and the
dispersion exponent kept. Nothing is written; nothing is tuned (docs/findings.md "Session 28: newuser9").
"""

from __future__ import annotations

import argparse
import sys

import numpy as np


def row(path: str) -> str:
    from impactsense.data import load_session
    from impactsense.signal import SignalConfig
    from impactsense.travel import fit_travel, picks, wants_metric

    s = load_session(path)
    cfg = SignalConfig.for_rig(s.rig)
    toa, period = picks(s.adc, cfg, with_period=True)
    aniso = wants_metric(s.rig)
    plain = fit_travel(toa, s.xy_mm, cfg.sensor_xy_mm, aniso)
    disp = fit_travel(toa, s.xy_mm, cfg.sensor_xy_mm, aniso, period, cfg.fs_hz)
    known = np.isfinite(period)
    med = float(np.median(period[known])) if known.any() else float("nan")
    return (f"{path:40s} {s.rig.fs_hz / 1e3:6.1f} {1 - known.mean():6.3f} {med:7.2f} {s.rig.fs_hz / med / 1e3:6.2f} "
            f"{np.mean(period[known] > 21.0) if known.any() else float('nan'):6.3f} {plain.spread_us:7.2f} "
            f"{disp.spread_us:7.2f} {disp.dispersion_exponent:6.3f}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="+")
    a = ap.parse_args(argv)
    print(f"{'session':40s} {'kHz':>6s} {'NaN':>6s} {'period':>7s} {'f kHz':>6s} {'>21':>6s} {'spread':>7s} "
          f"{'+disp':>7s} {'alpha':>6s}")
    for path in a.data:
        print(row(path))
    return 0


if __name__ == "__main__":
    sys.exit(main())
