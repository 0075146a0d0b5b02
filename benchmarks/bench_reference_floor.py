"""The residual reference's DToA floor (issue 16): the reference (physics + site terms) fitted on one half of a
session's cases and scored on the other, both ways, against the repeated drops' own scatter.

    python3 benchmarks/bench_reference_floor.py [--mean-levels] [SESSION ...]
        (default: the bundled session-1 and session-2; --mean-levels: `choose_picker` also tries the mean of the
        core's picks at several thresholds, `site_reference.MEAN_LEVEL_SETS`, which `diagnose` does not)

Prints, per session and for two timing picks (the AIC onset, and the picks `diagnose` reads:
`impactsense.site_reference.choose_picker`: the onset threshold, or the mean of the picks at several ("10 +
20"), the AIC blend and the dispersion, chosen on the session by held-out DToA) the held-out DToA rms of the
physics reference and of physics + site terms (`impactsense.site_reference.halves`; the site reference also in
each direction: fitted on the first half and scored on the second, then the other way), the within-case floor
(repeated drops at one declared position: pick noise plus landing scatter) and each reference's excess over
that floor (in quadrature), and the same site reference scored on each held-out case's mean over its repeated
drops (with the share of the within-case floor such a mean keeps: floor / sqrt(repeats)). A second table splits the floor and the excess (`site_reference.floor_parts`): the
picks' own noise against the landing scatter, the per-case timing error no position explains, the position
shift the case means ask for, and whether the per-case error is smooth (neighbouring cases against all pairs).
Target (exit 1 on a miss): the chosen picks' site reference held-out DToA <= 3 us rms on every session.
"""

from __future__ import annotations

import sys

TARGET_US = 3.0


def main(argv=None) -> int:
    from impactsense import residuals as R
    from impactsense.data import load_session
    from impactsense.site_reference import MEAN_LEVEL_SETS, choose_picker, floor_parts, halves

    args = list(argv if argv is not None else sys.argv[1:])
    level_sets = MEAN_LEVEL_SETS if "--mean-levels" in args else ()
    names = [a for a in args if a != "--mean-levels"] or ["bundled:session-1", "bundled:session-2"]
    miss = 0
    print("| session | drops | picks | physics us | + site terms us (each direction) | within-case floor us | "
          "excess over floor (physics / site) us | site, case means us | floor in a case mean us |")
    print("|---|---|---|---|---|---|---|---|---|")
    parts = []
    for name in names:
        session = load_session(name)
        F = R.extract(session)
        picker, _ = choose_picker(session, F, level_sets=level_sets)
        rows = [("AIC onset", F)]
        if picker is not None:
            levels = picker.get(R.LEVELS_KEY) or [picker["onset_threshold_counts"]]
            label = (f"threshold {' + '.join(f'{v:g}' for v in levels)}, blend {picker['aic_blend']:.2f}, "
                     f"dispersion {picker.get('dispersion_exponent', 0.0):.2f}")
            rows.append((label, R.repick(session, F, picker)))
        for label, Fp in rows:
            h = halves(Fp)
            each = " / ".join(f"{site:.2f}" for _, site in h["directions"])
            print(f"| {name} | {len(F)} | {label} | {h['physics']:.2f} | {h['site']:.2f} ({each}) | "
                  f"{h['within_case']:.2f} | {h['excess_physics']:.2f} / {h['excess_site']:.2f} | "
                  f"{h['site_case_mean']:.2f} | {h['case_mean_floor']:.2f} |", flush=True)
            parts.append((name, label, floor_parts(Fp)))
        miss += h["site"] > TARGET_US
    print("\n| session | picks | within-case floor us | pick noise us | landing us | per-case timing us (no position "
          "makes it) | case position shift mm | per-case DToA: neighbours / all pairs us |")
    print("|---|---|---|---|---|---|---|---|")
    for name, label, p in parts:
        print(f"| {name} | {label} | {p['within_case']:.2f} | {p['pick_noise']:.2f} | {p['landing']:.2f} | "
              f"{p['case_timing']:.2f} | {p['case_shift_mm']:.2f} | {p['case_near']:.2f} / {p['case_far']:.2f} |")
    print(f"\ntarget: held-out DToA <= {TARGET_US} us rms; misses: {miss}")
    return 1 if miss else 0


if __name__ == "__main__":
    sys.exit(main())
