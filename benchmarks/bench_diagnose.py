"""Before/after of the loop on the bundled sessions, and the diagnosis wall time.

    python benchmarks/bench_diagnose.py [--json OUT.json] [--only first,later]

Prints, for session-1 against the nominal model ("first") and session-2 against the session-1-calibrated
model ("later"), the effects found and DToA residual RMS (µs), physics-localiser MAE (mm) and log-energy
residual RMS before and after (out-of-fold) adding them.

Targets (exit 1 on a miss): the README's diagnosis within issue 16's tolerances (delay +-1 us, gain +-0.05):
- session-1 against the nominal model: channel delays on channels 2 and 3 (-5.4 / -6.3 us) and gains on
  channels 2 and 1 (x1.15 / x0.90) significant, nothing named on channel 0;
- session-2 against session-1: the strongest effect is channel 3's delay, -7.4 us;
- in both, the DToA residual and the physics localiser's MAE fall after the effects are added.
"""

from __future__ import annotations

import argparse
import json
import time

from impactsense.data import load_session
from impactsense.diagnose import diagnose

from benchlib import misses_exit_code

TOL = {"delay_us": 1.0, "gain": 0.05}          # issue 16
# (effect, sensor) -> (parameter, the README's value): what each diagnosis must name
EXPECTED = {
    "first": {("channel_delay", 2): ("delay_us", -5.4), ("channel_delay", 3): ("delay_us", -6.3),
              ("sensor_gain", 2): ("gain", 1.15), ("sensor_gain", 1): ("gain", 0.90)},
    "later": {("channel_delay", 3): ("delay_us", -7.4)},
}


def misses(key: str, res: dict) -> list[str]:
    """The targets this diagnosis misses (empty: met)."""
    sig = [e for e in res["effects"] if e["significant"]]
    named = {(e["effect"], e["sensor"]): e for e in sig}
    out = []
    for (effect, sensor), (param, want) in EXPECTED[key].items():
        e = named.get((effect, sensor))
        if e is None:
            out.append(f"{effect}[{sensor}] not named")
        elif abs(e["params"][param] - want) > TOL[param]:
            out.append(f"{effect}[{sensor}] {param} {e['params'][param]:+.2f} vs {want:+.2f} +- {TOL[param]}")
    if key == "later" and sig and (sig[0]["effect"], sig[0]["sensor"]) != ("channel_delay", 3):
        out.append(f"strongest effect {sig[0]['effect']}[{sig[0]['sensor']}], not channel_delay[3]")
    if key == "first" and any(e["sensor"] == 0 for e in sig):
        out.append("an effect named on channel 0 (the delays' and gains' reference)")
    for k in ("dtoa_rms_us", "mae_mm"):
        if not res["after"][k] < res["before"][k]:
            out.append(f"{k} did not fall ({res['before'][k]:.3f} -> {res['after'][k]:.3f})")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", default=None)
    ap.add_argument("--only", default="first,later", help="comma-separated: first, later")
    args = ap.parse_args(argv)
    s1 = load_session("bundled:session-1")
    s2 = load_session("bundled:session-2")
    runs = {"first": ("session-1 against the nominal model", s1, s1, True),
            "later": ("session-2 against session-1", s1, s2, False)}
    rows, missed = {}, []
    for key in args.only.split(","):
        label, base, data, same = runs[key]
        t = time.perf_counter()
        res, _ = diagnose(base, data, same=same)
        dt = time.perf_counter() - t
        found = [f"{e['effect']}[{e['sensor']}]" for e in res["effects"] if e["significant"]] or ["none"]
        bad = misses(key, res)
        missed += [f"{label}: {m}" for m in bad]
        rows[label] = {"effects": found, "before": res["before"], "after": res["after"], "seconds": dt,
                       "misses": bad}
        print(f"{label}: {', '.join(found)}  ({dt:.1f} s)")
        for e in res["effects"]:
            if e["significant"]:
                print(f"    {e['effect']}[{e['sensor']}] " + ", ".join(
                    f"{k}={v:+.3f}" for k, v in e["params"].items() if isinstance(v, (int, float))))
        for k in ("dtoa_rms_us", "mae_mm", "energy_rms"):
            print(f"    {k:<12} {res['before'][k]:8.3f} -> {res['after'][k]:8.3f}")
        want = ", ".join(f"{eff}[{s}] {p} {v:+.2f}" for (eff, s), (p, v) in EXPECTED[key].items())
        print(f"    target: {want} (delay +-{TOL['delay_us']} us, gain +-{TOL['gain']}); residuals fall: "
              + ("met" if not bad else "MISSED"))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    return misses_exit_code(missed)


if __name__ == "__main__":
    raise SystemExit(main())
