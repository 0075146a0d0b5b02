"""A loop session's per-drop pick change against its control (the same drops, landing jitter and noise, without
the change; `loop_sessions.py --controls`): per channel, the threshold picks' change (mean, sd, 5/50/95 %), the
changed channel's change split into the case means' and the within-case scatter, and the best constant-plus-move
fit of it (what a moved disc would make of it). A constant delay should shift every drop alike; on an aliased
onset a sub-sample delay re-draws the threshold crossing drop by drop (docs/findings.md, loopnames).

    python3 benchmarks/pick_change_vs_control.py DIR delay --channel 2 [--picker '{"onset_threshold_counts": 20}']

--picker: the picker `impactsense diagnose` chose (its summary.md prints it); default the core's own picks."""
import argparse
import json

import numpy as np

from impactsense import residuals as R
from impactsense.data import load_session


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sessions")
    ap.add_argument("name")
    ap.add_argument("--channel", type=int, required=True)
    ap.add_argument("--picker", default=None, help="JSON of the picker's settings")
    a = ap.parse_args(argv)
    picker = json.loads(a.picker) if a.picker else None
    s, c = load_session(f"{a.sessions}/{a.name}"), load_session(f"{a.sessions}/{a.name}-control")
    Fs, Fc = R.extract(s, picker), R.extract(c, picker)
    if not (np.allclose(Fs.x_mm, Fc.x_mm) and np.allclose(Fs.y_mm, Fc.y_mm)):
        raise SystemExit(f"{a.name}-control: not the same declared drops as {a.name}")
    D = Fs.toa_us - Fc.toa_us
    for ch in range(D.shape[1]):
        p = np.nanpercentile(D[:, ch], [5, 50, 95])
        print(f"ch{ch}: change mean {np.nanmean(D[:, ch]):+.2f} sd {np.nanstd(D[:, ch]):.2f} us; "
              f"5/50/95 % {p[0]:+.2f} / {p[1]:+.2f} / {p[2]:+.2f}")
    ch = a.channel
    y, cid = D[:, ch], Fs.case_id
    ok = np.isfinite(y)
    cases = np.unique(cid[ok])
    means = np.array([y[ok & (cid == k)].mean() for k in cases])
    within = np.concatenate([y[ok & (cid == k)] - y[ok & (cid == k)].mean() for k in cases])
    m = ok.sum() / cases.size
    print(f"ch{ch}: case means sd {means.std():.2f} us; within-case sd {within.std() * np.sqrt(m / (m - 1)):.2f} us "
          f"({m:.1f} drops a case)")
    sxy = s.rig.sensor_xy_mm.astype(float)
    dx, dy = Fs.x_mm - sxy[ch, 0], Fs.y_mm - sxy[ch, 1]
    d = np.hypot(dx, dy)
    ref = R.fit_reference(Fc, "calibrated")
    slow = ref.slowness_us_per_mm
    X = np.stack([np.ones(d.size), -slow * dx / d, -slow * dy / d], axis=1)
    coef, *_ = np.linalg.lstsq(X[ok], y[ok], rcond=None)
    print(f"ch{ch}: as a constant + a move of its disc: {coef[0]:+.2f} us, ({coef[1]:+.2f}, {coef[2]:+.2f}) mm "
          f"(slowness {slow:.3f} us/mm)")


if __name__ == "__main__":
    main()
