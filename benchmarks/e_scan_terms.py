"""The E scan's readings split into their terms (docs/findings.md "Session 23: estiff").

    python3 benchmarks/e_scan_terms.py SESSIONS TRUE_E_SCALE STEPS [loop_sessions options: --seed S --rig R ...]

SESSIONS a loop_sessions folder made with --controls (ref, stiffness, stiffness-control). Prints each slowness
statistic's E reading against the reference (as `plate_scan.e_scale_scan`) and against the control (the same
drops without the change), and the twin's miss (data ln s less the twin's at the declared drops, E unchanged) on
the reference's drops and on the changed session's: the reading is right when the two misses are equal.
"""
import json
import sys
import time
from pathlib import Path
import numpy as np
sys.path.insert(0, str(Path(__file__).parent))
import loop_sessions  # noqa: E402
from impactsense.data import load_session
from impactsense.diagnose import diagnose
from impactsense import plate_scan as P

folder, truth, nsteps = Path(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3])
extra = sys.argv[4:]
gen = loop_sessions.parse(["--out", str(folder)] + extra)
ref = load_session(folder / "ref"); new = load_session(folder / "stiffness"); ctrl = load_session(folder / "stiffness-control")
sim = loop_sessions.twin_params(loop_sessions.base_params(gen, ref.rig), gen)
t0 = time.time()
res, det = diagnose(ref, new, same=False)
picker = res["timing_picker"]
print("picker", picker, [ (e["effect"], e["params"].get("change_pct")) for e in res["effects"] if e["significant"]], flush=True)
stats = P.Statistics(ref, picker)
d = {k: stats(s) for k, s in (("ref", ref), ("new", new), ("ctrl", ctrl))}
print("data stats", d, flush=True)
tref = P.twin_statistics(sim, ref, 1.0, stats, P.SCAN_DRAWS, gen.seed, 2)
print("twin ref", {k: np.exp(v).round(5).tolist() for k, v in tref.items()}, time.time() - t0, flush=True)
ln_e, per = [], []
for k in range(nsteps + 1):
    e = 1.0 - 0.02 * k
    ln_e.append(np.log(e)); per.append(P.twin_statistics(sim, new, e, stats, P.SCAN_DRAWS, gen.seed, 2))
    print("E", e, {kk: float(np.mean(v)) for kk, v in per[-1].items()}, time.time() - t0, flush=True)
ln_e = np.array(ln_e)
out = {"truth": truth, "data": d, "twin_ref": {k: v.tolist() for k, v in tref.items()},
       "curve": [(float(np.exp(a)), {k: v.tolist() for k, v in q.items()}) for a, q in zip(ln_e, per)]}
for key in tref:
    c = np.array([np.mean(q[key]) for q in per])
    t_ref = np.log(d["new"][key]) - np.log(d["ref"][key]) + np.mean(tref[key])
    t_ctrl = np.log(d["new"][key]) - np.log(d["ctrl"][key]) + c[0]
    t_ctrl_own = np.log(d["ctrl"][key]) - c[0]
    miss_ref = np.log(d["ref"][key]) - np.mean(tref[key])
    r_ref = np.exp(P.crossing(ln_e, c, t_ref)[0]); r_ctrl = np.exp(P.crossing(ln_e, c, t_ctrl)[0])
    print(f"{key}: reading(ref) {100*(r_ref-1):+.2f}%  reading(ctrl) {100*(r_ctrl-1):+.2f}%  truth {100*(truth-1):+.2f}%"
          f"  miss(ref drops) {1e3*miss_ref:+.2f}e-3  miss(new drops,ctrl) {1e3*t_ctrl_own:+.2f}e-3"
          f"  slope {P.crossing(ln_e, c, t_ref)[1]:.3f}  sd(twin draws) {np.std(per[0][key], ddof=1)*1e3:.2f}e-3", flush=True)
    out[key] = {"ref": r_ref, "ctrl": r_ctrl, "miss_ref": miss_ref, "miss_new": t_ctrl_own}
Path(sys.argv[1].rstrip("/").split("/")[-1] + ".json").write_text(json.dumps(out, default=float))
