"""Before/after of the loop on the bundled sessions, and the diagnosis wall time.

    python benchmarks/bench_diagnose.py [--json OUT.json]

Prints, for session-1 against the nominal model and session-2 against the session-1-calibrated model, the
effects found and DToA residual RMS (µs), physics-localiser MAE (mm) and log-energy residual RMS before and
after (out-of-fold) adding them.
"""

from __future__ import annotations

import argparse
import json
import time

from impactsense.data import load_session
from impactsense.diagnose import diagnose


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    s1 = load_session("bundled:session-1")
    s2 = load_session("bundled:session-2")
    rows = {}
    for label, base, data, same in (("session-1 (first loop)", s1, s1, True),
                                    ("session-2 vs session-1", s1, s2, False)):
        t = time.perf_counter()
        res, _ = diagnose(base, data, same=same)
        dt = time.perf_counter() - t
        found = [f"{e['effect']}[{e['sensor']}]" for e in res["effects"] if e["significant"]] or ["none"]
        rows[label] = {"effects": found, "before": res["before"], "after": res["after"], "seconds": dt}
        print(f"{label}: {', '.join(found)}  ({dt:.1f} s)")
        for k in ("dtoa_rms_us", "mae_mm", "energy_rms"):
            print(f"    {k:<12} {res['before'][k]:8.3f} -> {res['after'][k]:8.3f}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
