"""The residual reference's DToA floor (issue 16): the reference (physics + site terms) fitted on one half of a
session's cases and scored on the other, both ways, against the repeated drops' own scatter.

    python3 benchmarks/bench_reference_floor.py [SESSION ...]   (default: the bundled session-1)

Prints, per session and for two timing picks (the AIC onset, and the picks `diagnose` reads:
`impactsense.site_reference.choose_picker`, onset threshold, AIC blend and dispersion chosen on the session by
held-out DToA), the held-out DToA rms of the physics reference and of physics + site terms
(`impactsense.site_reference.halves`), the within-case floor (repeated drops at one declared position: pick
noise plus landing scatter) and each reference's excess over that floor (in quadrature). Target (exit 1 on a
miss): the chosen picks' site reference held-out DToA <= 3 us rms.
"""

from __future__ import annotations

import sys

TARGET_US = 3.0


def main(argv=None) -> int:
    from impactsense import residuals as R
    from impactsense.data import load_session
    from impactsense.site_reference import choose_picker, halves

    names = (argv if argv is not None else sys.argv[1:]) or ["bundled:session-1"]
    miss = 0
    print("| session | drops | picks | physics us | + site terms us | within-case floor us | excess over floor (physics / site) us |")
    print("|---|---|---|---|---|---|---|")
    for name in names:
        session = load_session(name)
        F = R.extract(session)
        picker, _ = choose_picker(session, F)
        rows = [("AIC onset", F)]
        if picker is not None:
            label = (f"threshold {picker['onset_threshold_counts']:g}, blend {picker['aic_blend']:.2f}, "
                     f"dispersion {picker.get('dispersion_exponent', 0.0):.2f}")
            rows.append((label, R.repick(session, F, picker)))
        for label, Fp in rows:
            h = halves(Fp)
            print(f"| {name} | {len(F)} | {label} | {h['physics']:.2f} | {h['site']:.2f} | {h['within_case']:.2f} | "
                  f"{h['excess_physics']:.2f} / {h['excess_site']:.2f} |", flush=True)
        miss += h["site"] > TARGET_US
    print(f"\ntarget: held-out DToA <= {TARGET_US} us rms; misses: {miss}")
    return 1 if miss else 0


if __name__ == "__main__":
    sys.exit(main())
