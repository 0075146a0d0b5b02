"""Can the board's 50 kHz picks use a dispersion correction? The physics position (MAE per axis, x and y averaged,
the held-out drops of the model's split) of the board's picks and of the host's picks, each with a per-pick
slowness factor, over localiser starts and posterior grids.

    python benchmarks/bench_board_dispersion.py DATA --model M --export OUT

M: `impactsense train DATA --out M` (the host's signal at the rig's rate: its dispersion exponent and reference);
OUT: `impactsense export M --out OUT` (the board refit's signal, OUT/board-model/model_card.json). Both pick
sets are those of the drops the emulated board captured (board_captures). Each pick set keeps its
model's localiser (velocity, channel delays, metric); a row multiplies each pick's travel time by a factor
(normalised to the training picks' median, so the model's velocity stays the typical pick's) and runs the core's
localiser (localise_batch) on the held-out drops. Rows:
- no factor (the board's: the export's physics position);
- the host's dispersion factor (f / f_ref)^-alpha from the host's picked-cycle frequency at the rig's rate (an
  oracle for the board: the board cannot measure it), per channel, and its drop mean only;
- the board's own picked-cycle frequency unfolded about the board's Nyquist frequency (fs - f: no anti-alias
  filter, so a cycle above fs / 2 reads as fs - f), alpha 0.15;
- the slowness linear in the drops' summed log energy (travel.fit_energy_slowness: impact energy sets the
  contact time and so the spectrum);
- a second localiser run with a factor (d / median d)^0.1 of each channel's distance from the first run's position.
Prints a table; exits 0. A diagnosis (Python fits on the core's picks), not the export's path.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

STARTS_GRIDS = ((1, 0), (2, 0), (4, 0), (1, 5), (2, 5), (4, 15))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data")
    ap.add_argument("--model", type=Path, required=True, help="the host model (impactsense train)")
    ap.add_argument("--export", type=Path, required=True, help="its board export (impactsense export)")
    ap.add_argument("--fs", type=int, default=50000, help="the board's rate")
    args = ap.parse_args()

    from impactsense import _core
    from impactsense.board.capture import board_captures
    from impactsense.data import load_session
    from impactsense.pipeline import featurize
    from impactsense.signal import SignalConfig
    from impactsense.travel import TravelFit, fit_energy_slowness, slowness_scales, summed_log_energy

    session = load_session(args.data)
    host_card = json.loads((args.model / "model_card.json").read_text())
    board_signal = json.loads((args.export / "board-model" / "model_card.json").read_text())["signal"]
    caps, rows, bcfg = board_captures(session, args.fs, board_signal)
    board = featurize(caps, SignalConfig.from_dict(board_signal))
    hsig = SignalConfig.from_dict(host_card["signal"])
    host = featurize(session.adc[rows], hsig)
    rid = session.recording_id[rows]
    train = np.isin(rid, [int(r) for r in host_card["split"]["train_recordings"]])
    test = np.isin(rid, [int(r) for r in host_card["split"]["test_recordings"]])
    xy = np.asarray(session.xy_mm, float)[rows]
    b = SignalConfig.from_dict(board_signal).to_dict()
    sensors = bcfg.sensor_xy_mm
    metric = (b["travel_metric_xx"], b["travel_metric_xy"], b["travel_metric_yy"])
    dist = np.hypot(xy[:, None, 0] - sensors[None, :, 0], xy[:, None, 1] - sensors[None, :, 1])
    one = np.ones(dist.shape)

    def locate(toa, scale, s, delays, which, starts, grid):
        t = toa[which] - delays[None]
        use = np.isfinite(t).astype(np.uint8)
        out = _core.localise_batch(np.where(use, t, 0).astype(np.float32), use, list(sensors[:, 0]),
                                   list(sensors[:, 1]), float(1.0 / s), float(b["sigma_us"]), float(b["plate_x_mm"]),
                                   float(b["plate_y_mm"]), float(b["huber_us"]), list(metric),
                                   list(np.asarray(scale[which], np.float32).ravel()), starts, grid, 0)
        return np.c_[out["x_mm"], out["y_mm"]]

    def row(name, toa, scale, velocity):
        scale = scale / np.nanmedian(scale[train])   # the model's velocity stays the median pick's
        s, delays = 1.0 / velocity, np.zeros(4)      # toa_us: the model's delays already off
        cells = []
        for starts, grid in STARTS_GRIDS:
            p = locate(toa, scale, s, delays, test, starts, grid)
            ok = np.isfinite(p).all(1)
            cells.append(f"{np.abs(p[ok] - xy[test][ok]).mean():8.2f}")
        print(f"{name:<52}" + "".join(cells), flush=True)

    btoa = board.raw["toa_us"].astype(float)
    htoa = host.raw["toa_us"].astype(float)
    hs = slowness_scales(host.raw["pick_period"], hsig.fs_hz, float(host_card["signal"]["dispersion_exponent"]),
                         float(host_card["signal"]["dispersion_ref_hz"]))
    hs_mean = np.exp(np.log(hs).mean(1, keepdims=True)) * one
    fb = float(args.fs) / np.asarray(board.raw["pick_period"], float)
    unfolded = np.where(np.isfinite(fb), ((args.fs - np.clip(fb, 1e3, 0.499 * args.fs)) /
                                          float(host_card["signal"]["dispersion_ref_hz"])) ** -0.15, 1.0)
    le = summed_log_energy(board.raw["energy"], float(args.fs))
    vb, vh = float(b["velocity_mm_per_us"]), float(hsig.velocity_mm_per_us)
    line = fit_energy_slowness(btoa[train], xy[train], sensors, TravelFit(vb, [0.0] * 4, metric, 0.0, 0), le[train])
    energy = one if line is None else np.nan_to_num((1.0 + line[0] * line[1] * (le - line[2]))[:, None] * one, nan=1.0)
    first = locate(btoa, one, 1.0 / vb, np.zeros(4), np.arange(len(btoa)), 1, 0)
    dhat = np.hypot(first[:, None, 0] - sensors[None, :, 0], first[:, None, 1] - sensors[None, :, 1])
    second = np.where(np.isfinite(dhat), (np.maximum(dhat, 20.0) / np.median(dist)) ** 0.1, 1.0)

    print(f"{session.path}: physics MAE per axis (mm), {int(test.sum())} held-out drops; columns: starts, grid")
    print(" " * 52 + "".join(f"{f'{s}, {g}':>8}" for s, g in STARTS_GRIDS))
    row(f"board picks ({args.fs / 1000:g} kHz), no factor", btoa, one, vb)
    row("  the host's frequency per channel (oracle)", btoa, hs, vb)
    row("  the host's frequency, drop mean (oracle)", btoa, hs_mean, vb)
    row("  the board's frequency unfolded, alpha 0.15", btoa, unfolded, vb)
    row("  slowness linear in summed log energy", btoa, energy, vb)
    row("  second run, distance^0.1 from the first", btoa, second, vb)
    row(f"host picks ({hsig.fs_hz / 1000:g} kHz), no factor", htoa, one, vh)
    row("  the host's frequency per channel (its dispersion)", htoa, hs, vh)
    return 0


if __name__ == "__main__":
    sys.exit(main())
