"""How rough the core's picks are in the hit position: noise-free FEM drops along short lines, picked.

    python3 benchmarks/pick_roughness.py [--rig SESSION_DIR] [--calibration rig|CAL.json] [--element-mm 3.0]
        [--step-mm 0.4] [--length-mm 12] [--height-mm 150] [--baseline DIR]

Drops at one height every --step-mm along two --length-mm lines (the benchmark's twin: `loop_sessions.py`'s
mesh and window; no noise, no landing scatter), picked by the core with each picker below; per channel, the
drop-centred ToA less a quadratic in the position along the line (what a smooth function of position can take),
its rms. A reference learned at positions ~40 mm apart (the loop's 80 cases) cannot learn what varies within a
few mm: this is the part of the per-case error that is a deterministic function of where the ball hit.
Pickers: the default AIC onset, the threshold crossing (blend 0), the mean of the crossings at four thresholds
(`residuals.core_picks` levels), and with --baseline DIR the picker `choose_picker` chooses on DIR (diagnose's)."""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def line_drops(rig, length_mm: float, step_mm: float):
    """Two lines, at 30 % and 65 % of the plate, along (0.8, 0.6)."""
    t = np.arange(0.0, length_mm + 1e-9, step_mm)
    starts = [(0.3 * rig.plate_x_mm, 0.3 * rig.plate_y_mm), (0.65 * rig.plate_x_mm, 0.65 * rig.plate_y_mm)]
    x = np.concatenate([x0 + 0.8 * t for x0, _ in starts])
    y = np.concatenate([y0 + 0.6 * t for _, y0 in starts])
    return x, y, t, len(starts)


def roughness(toa: np.ndarray, t: np.ndarray, lines: int) -> np.ndarray:
    """[lines, 4] rms of each channel's drop-centred ToA less a quadratic in t along each line."""
    n = t.size
    out = np.zeros((lines, toa.shape[1]))
    for k in range(lines):
        v = toa[k * n:(k + 1) * n]
        v = v - v.mean(axis=1, keepdims=True)
        for c in range(v.shape[1]):
            out[k, c] = np.std(v[:, c] - np.polyval(np.polyfit(t, v[:, c], 2), t))
    return out


def main(argv=None) -> int:
    import loop_sessions as LS
    from impactsense import residuals as R
    from impactsense.data import bundled_session_path, load_session, write_session
    from impactsense.sim import simulate_drops
    from impactsense.signal import core_config

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rig", default=str(bundled_session_path("session-1")))
    ap.add_argument("--calibration", default="rig")
    ap.add_argument("--element-mm", type=float, default=3.0)
    ap.add_argument("--duration-ms", type=float, default=10.0)
    ap.add_argument("--step-mm", type=float, default=0.4)
    ap.add_argument("--length-mm", type=float, default=12.0)
    ap.add_argument("--height-mm", type=float, default=150.0)
    ap.add_argument("--baseline", default=None, help="a session folder: also the picker choose_picker chooses on it")
    args = ap.parse_args(argv)
    rig = load_session(args.rig).rig
    params = LS.twin_params(LS.base_params(args, rig), args)
    x, y, t, lines = line_drops(rig, args.length_mm, args.step_mm)
    adc = simulate_drops(params, rig, x, y, np.full(x.size, args.height_mm), noise=False, seed=0, workers=1,
                         progress=False)
    with tempfile.TemporaryDirectory() as tmp:
        write_session(Path(tmp) / "line", rig, x, y, np.full(x.size, args.height_mm), adc, np.arange(x.size),
                      np.zeros(x.size, int))
        S = load_session(Path(tmp) / "line")
        thr = float(core_config(rig).onset_threshold_counts)
        blend = float(core_config(rig).aic_blend)
        pickers = {"AIC onset (default)": None,
                   f"threshold {thr:g} counts, blend 0": {"onset_threshold_counts": thr, "aic_blend": 0.0},
                   f"mean of thresholds {thr:g} x (1, 1.5, 2, 3), blend {blend:g}":
                       {"onset_threshold_counts": thr, "aic_blend": blend,
                        R.LEVELS_KEY: [thr * f for f in (1.0, 1.5, 2.0, 3.0)]}}
        if args.baseline:
            from impactsense.site_reference import choose_picker
            pickers["diagnose's (choose_picker on --baseline)"] = choose_picker(load_session(args.baseline))[0]
        print(f"{x.size} noise-free drops on {lines} lines of {args.length_mm:g} mm every {args.step_mm:g} mm; "
              f"mesh {args.element_mm:g} mm; fs {rig.fs_hz / 1e3:g} kHz (a sample {1e6 / rig.fs_hz:.1f} us)")
        for label, picker in pickers.items():
            rough = roughness(R.extract(S, picker).toa_us, t, lines)
            print(f"  {label}: rms per line x channel (us) {np.round(rough, 2).tolist()}; mean {rough.mean():.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
