"""impactsense info DATA"""

from __future__ import annotations


ORDER = 10


def register(sub) -> None:
    p = sub.add_parser("info", help="summarise a session: drops, cases, heights, clipping, noise, SNR",
                       description="Reads and validates a session folder and summarises it.")
    p.add_argument("data", nargs="?", default="bundled", help="session folder (default: bundled session-1)")
    p.add_argument("--json", dest="json_out", default=None, help="also write the summary as JSON")
    p.set_defaults(func=run)


def summarise(session) -> dict:
    import numpy as np

    from ..pipeline import featurize
    from ..signal import SignalConfig

    feats = featurize(session.adc, SignalConfig.for_rig(session.rig))
    noise = feats.raw["noise_rms"]
    peak = feats.raw["peak"]
    snr_db = 20 * np.log10(np.maximum(peak, 1e-6) / np.maximum(noise, 1e-6))
    reps = np.bincount(session.case_id)
    reps = reps[reps > 0]
    heights, counts = np.unique(session.height_mm, return_counts=True)
    base = SignalConfig.for_rig(session.rig).baseline_samples
    level = np.median(session.adc[:, :, :base].astype(float), axis=(0, 2))   # each channel's level before the hit
    return {
        "plate": plate_summary(session.rig),
        "level_minus_bias_counts": [float(v - session.rig.bias_counts) for v in level],
        "session": str(session.path),
        "drops": len(session),
        "cases": session.n_cases,
        "repetitions_per_case": {"min": int(reps.min()), "median": float(np.median(reps)), "max": int(reps.max())},
        "heights_mm": {"min": float(heights.min()), "max": float(heights.max()), "distinct": int(heights.size)},
        "drops_per_height": {f"{h:g}": int(c) for h, c in zip(heights, counts)},
        "samples": int(session.adc.shape[2]),
        "fs_hz": session.rig.fs_hz,
        "pretrigger_samples": session.rig.pretrigger_samples,
        "baseline_samples": int(SignalConfig.for_rig(session.rig).baseline_samples),
        "channels": [
            {
                "channel": c,
                "sensor": session.rig.sensors[c].name,
                "clipped_drops": int(feats.clipped[:, c].sum()),
                "dead_drops": int(feats.dead[:, c].sum()),
                "no_onset_drops": int(feats.no_onset[:, c].sum()),
                "noise_rms_counts": float(np.median(noise[:, c])),
                "peak_counts_median": float(np.median(peak[:, c])),
                "snr_db_median": float(np.median(snr_db[:, c])),
            }
            for c in range(4)
        ],
        "usable_drops": int(feats.usable.sum()),
    }


def plate_summary(rig) -> dict:
    """What the project takes the plate to be: the materials table's entry for rig.json's words (or unknown:
    wide priors), its kind and axes, and the density with where it came from."""
    from ..materials import material_for_rig

    mat = material_for_rig(rig)
    return {"material": mat.name if mat.known else "unknown to the materials table (wide priors)",
            "kind": mat.kind, "axis_deg": mat.axis_deg, "density_kg_m3": rig.density_kg_m3,
            "density_from": "rig.json" if "density_kg_m3" in rig.raw else "the materials table (not in rig.json)"}


def run(args) -> int:

    from ..data import load_session

    session = load_session(args.data)
    s = summarise(session)
    print(f"{s['session']}")
    print(f"  drops {s['drops']}, cases {s['cases']}, repetitions per case "
          f"{s['repetitions_per_case']['min']}..{s['repetitions_per_case']['max']}")
    print(f"  heights {s['heights_mm']['min']:g}..{s['heights_mm']['max']:g} mm "
          f"({s['heights_mm']['distinct']} distinct); {s['samples']} samples at {s['fs_hz']:g} Hz")
    pl = s["plate"]
    axes = f", axis 1 at {pl['axis_deg']:g} deg" if pl["kind"] == "orthotropic" else ""
    print(f"  plate: {pl['material']} ({pl['kind']}{axes}), density {pl['density_kg_m3']:g} kg/m3 from "
          f"{pl['density_from']}")
    off = s["level_minus_bias_counts"]
    print(f"  level before the hit less the declared bias (counts): {', '.join(f'{v:+.0f}' for v in off)}")
    pre = s["pretrigger_samples"]
    print(f"  samples before the first arrival: {'unknown' if pre is None else pre}; the core's baseline segment "
          f"{s['baseline_samples']} samples")
    print(f"  usable drops (onset on all 4 channels): {s['usable_drops']}")
    print(f"  {'ch':>2s} {'sensor':>6s} {'clipped':>8s} {'dead':>5s} {'noise rms':>10s} {'median peak':>12s} {'SNR dB':>7s}")
    for c in s["channels"]:
        print(f"  {c['channel']:2d} {c['sensor']:>6s} {c['clipped_drops']:8d} {c['dead_drops']:5d} "
              f"{c['noise_rms_counts']:10.2f} {c['peak_counts_median']:12.0f} {c['snr_db_median']:7.1f}")
    if args.json_out:
        from ..outputs import json_text, write_file

        write_file(args.json_out, json_text(s))
        print(f"wrote {args.json_out}")
    return 0
