"""impactsense info DATA"""

from __future__ import annotations

import numpy as np

ORDER = 10
HUM_QUIET_S = 15e-3   # a quiet start at least this long (3/4 of a 50 Hz period) is where the hum is read


def hum_counts(session) -> tuple[np.ndarray, str, np.ndarray, np.ndarray, float]:
    """Each channel's median 50 / 60 Hz hum amplitude (counts) over the drops, the larger of the two, where it
    was read: the quiet start before the hit when the logger keeps HUM_QUIET_S of it, else the record's tail
    (diagnose's, residuals.tail_start), the median amplitude white noise alone would stay under there
    (hum.hum_floor), each channel's median amplitude at each of hum.HUM_HZ [4, 2] and the segment's span (ms, its
    first to its last sample). The core's noise rms reads its baseline segment only, a few ms: the hum looks like an
    offset there."""
    from ..hum import hum_floor, hum_lock_in, quiet_index
    from ..residuals import tail_start

    fs, n = float(session.rig.fs_hz), session.adc.shape[2]
    pre = session.rig.pretrigger_samples
    index = None
    if pre is not None and pre >= HUM_QUIET_S * fs:
        seg, where = slice(0, int(pre) - 16), "the quiet start"
    else:
        # neither a quiet start of HUM_QUIET_S nor a tail of a few ms tells 50 from 60 Hz, offset and the plate's
        # own slow ringing apart; the two together, on the record's time axis, span the record
        index = quiet_index(session.adc, fs, int(pre)) if pre is not None and n >= HUM_QUIET_S * fs else None
        if index is not None:
            t0_ms = index[int(pre) - min(16, int(pre) // 4)] / fs * 1e3
            seg, where = index, f"the quiet start and the record's tail from {t0_ms:.1f} ms"
        else:
            seg, where = slice(tail_start(n, fs), n), "the record's tail"
    quiet = session.adc[:, :, seg].astype(np.float32) - session.rig.bias_counts
    hum, _, left = hum_lock_in(quiet, fs, index)
    floor = hum_floor(quiet.shape[2], fs, left, index)
    picked = np.arange(n)[seg] if index is None else np.asarray(index)
    span_ms = float(picked[-1] - picked[0] + 1) / fs * 1e3
    return np.median(hum.max(axis=2), axis=0), where, np.median(floor, axis=0), np.median(hum, axis=0), span_ms


def register(sub) -> None:
    p = sub.add_parser("info", help="summarise a session: drops, cases, heights, clipping, noise, SNR",
                       description="Reads and validates a session folder and summarises it.")
    p.add_argument("data", nargs="?", default="bundled", help="session folder (default: bundled session-1)")
    p.add_argument("--json", dest="json_out", default=None, help="also write the summary as JSON")
    p.set_defaults(func=run)


def summarise(session) -> dict:
    from ..pipeline import featurize
    from ..hum import HUM_HZ
    from ..record_window import window_check
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
    hum, hum_where, hum_floor, hum_each, hum_span_ms = hum_counts(session)
    from ..hum import hum_readable

    readable = hum_readable(hum, hum_floor, session.rig.adc_max)
    return {
        "plate": plate_summary(session.rig),
        "ball": ball_summary(session.rig),
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
        "hum_read_over": hum_where,
        "hum_read_span_ms": hum_span_ms,
        "channels": [
            {
                "channel": c,
                "sensor": session.rig.sensors[c].name,
                "clipped_drops": int(feats.clipped[:, c].sum()),
                "dead_drops": int(feats.dead[:, c].sum()),
                "no_onset_drops": int(feats.no_onset[:, c].sum()),
                "noise_rms_counts": float(np.median(noise[:, c])),
                "hum_counts": float(hum[c]) if readable[c] else None,
                "hum_floor_counts": float(hum_floor[c]) if readable[c] else None,
                "hum_hz": float(HUM_HZ[int(np.argmax(hum_each[c]))]) if readable[c] else None,
                "peak_counts_median": float(np.median(peak[:, c])),
                "snr_db_median": float(np.median(snr_db[:, c])),
            }
            for c in range(4)
        ],
        "usable_drops": int(feats.usable.sum()),
        "record_window": window_check(session.rig, int(session.adc.shape[2]), session.rig.pretrigger_samples),
    }


def plate_summary(rig) -> dict:
    """What the project takes the plate to be: the materials table's entry for rig.json's words (or unknown:
    wide priors), its kind and axes, and the density with where it came from."""
    from ..materials import material_for_rig

    mat = material_for_rig(rig)
    words = rig.raw.get("plate_material", "")
    return {"material": mat.name if mat.known else f"{words!r}: unknown to the materials table (wide priors; "
                                                   "declare material_properties to narrow them)",
            "kind": mat.kind, "axis_deg": mat.axis_deg, "density_kg_m3": rig.density_kg_m3,
            "density_from": "rig.json" if "density_kg_m3" in rig.raw else "the materials table (not in rig.json)",
            "priors": {n: p.to_dict() for n, p in mat.constants().items()}}


def priors_text(priors: dict) -> str:
    """The plate's prior constants in a line: moduli in GPa, typical (range)."""
    def one(name, p):
        scale, label = (1e-9, name.replace("_pa", "") + " GPa") if name.endswith("_pa") else (1.0, name)
        return f"{label} {p['value'] * scale:.3g} ({p['lo'] * scale:.3g}..{p['hi'] * scale:.3g})"
    return ", ".join(one(n, p) for n, p in priors.items())


def ball_summary(rig) -> dict:
    """The ball the twin's Hertz contact takes (balls.ball_for_rig): its name, E, nu and where they came from."""
    from ..balls import ball_for_rig

    ball = ball_for_rig(rig)
    return {"material": ball.name if ball.known else f"{rig.ball_material!r}: not in the ball table, taken as steel",
            "e_pa": ball.e_pa, "nu": ball.nu, "from": ball.source}


def hum_text(channel: dict) -> str:
    """The hum column: the amplitude, '<floor' when white noise alone would read as much, 'n/a' when the segment
    cannot read a hum the logger could record (`hum_readable`)."""
    if channel["hum_counts"] is None:
        return "n/a"
    if channel["hum_counts"] < channel["hum_floor_counts"]:
        return f"<{channel['hum_floor_counts']:.1f}"
    hz = channel.get("hum_hz")
    return f"{channel['hum_counts']:.1f}" + ("" if hz is None else f"@{hz:.0f}")


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
          f"{pl['density_from']}; priors {priors_text(pl['priors'])}")
    b = s["ball"]
    print(f"  ball: {b['material']}, E {b['e_pa'] / 1e9:.3g} GPa, nu {b['nu']:.2f} (the twin's contact; from "
          f"{b['from']}), {session.rig.ball_diameter_mm:g} mm, {session.rig.ball_mass_g:g} g")
    off = s["level_minus_bias_counts"]
    print(f"  level before the hit less the declared bias (counts): {', '.join(f'{v:+.0f}' for v in off)}")
    pre = s["pretrigger_samples"]
    print(f"  samples before the first arrival: {'unknown' if pre is None else pre}; the core's baseline segment "
          f"{s['baseline_samples']} samples")
    from ..record_window import window_text

    print(f"  {window_text(s['record_window'])}")
    print(f"  usable drops (onset on all 4 channels): {s['usable_drops']}")
    print(f"  {'ch':>2s} {'sensor':>6s} {'clipped':>8s} {'dead':>5s} {'noise rms':>10s} {'hum':>9s} {'median peak':>12s} "
          f"{'SNR dB':>7s}")
    for c in s["channels"]:
        print(f"  {c['channel']:2d} {c['sensor']:>6s} {c['clipped_drops']:8d} {c['dead_drops']:5d} "
              f"{c['noise_rms_counts']:10.2f} {hum_text(c):>9s} {c['peak_counts_median']:12.0f} "
              f"{c['snr_db_median']:7.1f}")
    print(f"  (noise rms: the core's baseline segment; hum: 50/60 Hz amplitude over {s['hum_read_over']}, median "
          f"over the drops, @ the mains frequency that reads larger; '<F': under F, what the noise alone reads "
          f"there: no hum seen)")
    if any(c["hum_counts"] is None for c in s["channels"]):
        span_ms = s["hum_read_span_ms"]
        print(f"  (hum n/a: {span_ms:.1f} ms of the record is too small a part of a mains period (20 ms at 50 Hz) to "
              f"tell a hum from the record's offset, trend and ringing: the lock-in reads more than the ADC's half "
              f"range; record at least 15 ms before the hit to see the hum)")
    if args.json_out:
        from ..outputs import json_text, write_file

        write_file(args.json_out, json_text(s))
        print(f"wrote {args.json_out}")
    return 0
