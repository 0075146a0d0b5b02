"""E's size on a loop draw's stiffness session, weighted as before and after the position-set term
(docs/findings.md "Session 24: ehalves").

    python3 benchmarks/e_halves.py SESSIONS [loop_sessions options: --seed S --rig R --calibration rig ...]

SESSIONS a loop_sessions folder with ref and stiffness (its manifest holds the truth). Runs diagnose as
bench_loop does and `plate_scan.e_scale_scan` on the wave_speed candidate with bench_loop's seed, and prints
each reading, its sd terms (the twin's draw scatter, the position-set term from DATA_REF's halves), and the
answer and interval weighted by the draw scatter alone (before) and by `reading_sd` (after: both terms). Writes
NAME.ehalves.json in the working directory.
"""
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
import loop_sessions  # noqa: E402
from impactsense import plate_scan as P  # noqa: E402
from impactsense.data import load_session  # noqa: E402
from impactsense.diagnose import _param_ci, _param_se, diagnose  # noqa: E402


def weighted(got: dict, sd: dict) -> float:
    w = {n: 1.0 / max(v, 1e-6) ** 2 for n, v in sd.items()}
    return sum(w[n] * np.log(got[n]) for n in w) / sum(w.values())


def main(argv) -> int:
    folder = Path(argv[0])
    gen = loop_sessions.parse(["--out", str(folder)] + argv[1:])
    man = json.loads((folder / "manifest.json").read_text())
    truth = man["sessions"]["stiffness"]["truth"]["params"]["e_scale"]
    ref, new = load_session(folder / "ref"), load_session(folder / "stiffness")
    sim = loop_sessions.twin_params(loop_sessions.base_params(gen, ref.rig), gen)
    t0 = time.time()
    res, det = diagnose(ref, new, same=False)
    cand = [c for c in det["accepted"] if c.effect == "wave_speed"]
    print("named", [(e["effect"], e["sensor"]) for e in res["effects"] if e["significant"]], flush=True)
    if not cand:
        print("no wave_speed candidate accepted")
        return 1
    c = cand[0]
    ci = _param_ci(c, _param_se(c)).get("change_pct")
    scan = P.e_scale_scan(sim, new, res["timing_picker"], c.params["change_pct"], ref, ci, gen.seed, 2)
    got = {n: scan["readings"][n] for n in scan["sd_terms"]}
    terms = scan["sd_terms"]
    old_sd = {n: t["draws"] for n, t in terms.items()}
    slope = {"pick": (np.log(scan["readings"]["pick"]), -scan["exponent"])}
    rows = {}
    for name, sd in (("before (draw scatter)", old_sd), ("after (+ position-set term)", scan["reading_sd"])):
        a = weighted(got, sd)
        iv = P._interval(a, slope, sd, ci)
        rows[name] = {"e_pct": 100 * (np.exp(a) - 1),
                      "lo": 100 * (iv["e_scale_lo"] - 1), "hi": 100 * (iv["e_scale_hi"] - 1)}
    print(f"{folder}: truth E {100 * (truth - 1):+.2f} %  ({time.time() - t0:.0f} s)")
    for n, v in scan["readings"].items():
        t = terms.get(n, {})
        print(f"  reading {n}: {100 * (v - 1):+.2f} %  sd draws {100 * t.get('draws', np.nan):.2f}  "
              f"positions {100 * t.get('positions', np.nan):.2f} (points of ln E)")
    for name, r in rows.items():
        print(f"  {name}: E {r['e_pct']:+.2f} % (error {r['e_pct'] - 100 * (truth - 1):+.2f}) "
              f"[{r['lo']:+.1f}, {r['hi']:+.1f}]")
    print(f"  scan's own: E {100 * (scan['e_scale'] - 1):+.2f} % [{100 * (scan['e_scale_lo'] - 1):+.1f}, "
          f"{100 * (scan['e_scale_hi'] - 1):+.1f}]")
    out = {"truth": truth, "readings": scan["readings"], "sd_terms": terms, "rows": rows,
           "e_scale": scan["e_scale"], "e_scale_lo": scan["e_scale_lo"], "e_scale_hi": scan["e_scale_hi"]}
    Path(f"{folder.name}.ehalves.json").write_text(json.dumps(out, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
