"""`impactsense retrain` on session-2: the session-1 model before and after retraining, with and without the twin.

Session-2 (a later day) has one undeclared change against session-1: channel 3 reads ~7 us early. The retrained
model is trained on session-1's recordings with the diagnosed effects put in (commands/retrain.py); the
baseline model on session-1 as it is; both on the same case split (--seed, 20 % of the cases held out) and
scored on every session-2 drop. Rows with "site map none" are the forests alone (retrain before it trained
with the twin: no uncertainty). Printed per model: position MAE whole plate / inner region (mean of the x and
y MAE, mm), the physics localiser's MAE, energy class accuracy, and the share of the radial errors within 1x
and 2x the reported uncertainty (a 1-sigma: 0.63 / 0.98 for a 2-D Gaussian). --board adds the same two twin
models exported (4 x 50 kHz, --trees 10) and run through the emulated board (firmware app) on session-2.

    python benchmarks/bench_retrain.py [--seed 0] [--trees 100] [--board]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from impactsense.commands.retrain import augment, score
from impactsense.data import load_session, write_session
from impactsense.diagnose import diagnose
from impactsense.models import ForestSettings
from impactsense.sitemap import resolve_site_map
from impactsense.workflow import train

MODELS = Path(__file__).resolve().parents[1] / "models"
HEADER = f"{'':<36} {'MAE mm':>7} {'inner':>6} {'phys':>6} {'class':>6} {'1u':>5} {'2u':>5}"


def row(label, v) -> str:
    return (f"{label:<36} {v['mae_mm']:7.2f} {v['inner_mae_mm']:6.2f} {v.get('physics_mae_mm', np.nan):6.2f} "
            f"{v['energy_class_accuracy']:6.3f} {v['within_1u']:5.2f} {v['within_2u']:5.2f}")


def board_score(export_dir: Path, s) -> dict:
    """The exported tables through the emulated board over every drop of `s`."""
    from impactsense.export import firmware_models
    from impactsense.board.scores import board_reports
    from impactsense.metrics import region_metrics
    from impactsense.models import impact_energy_j

    models, signal = firmware_models(export_dir)
    got = board_reports(s, models, signal)
    rows = np.array(sorted(got))
    xy = np.array([[got[i]["x_mm"], got[i]["y_mm"]] for i in rows])
    err = np.hypot(*(xy - s.xy_mm[rows]).T)
    u = np.array([got[i]["uncertainty_mm"] for i in rows])
    threshold = json.loads((export_dir / "board-model" / "model_card.json").read_text())["energy_threshold_j"]
    label = impact_energy_j(s.height_mm[rows], s.rig.ball_mass_g) >= threshold
    cls = np.array([got[i]["energy_class"] for i in rows])
    m = region_metrics(s.xy_mm[rows], xy, s.rig.inner_region_mm)
    return {"mae_mm": m["all"]["mae_mm"], "inner_mae_mm": m["inner"]["mae_mm"], "reported": len(rows),
            "energy_class_accuracy": float(np.mean(cls == label)),
            "within_1u": float(np.mean(err <= u)), "within_2u": float(np.mean(err <= 2 * u))}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--trees", type=int, default=100)
    ap.add_argument("--board", action="store_true")
    args = ap.parse_args()
    s1, s2 = load_session("bundled:session-1"), load_session("bundled:session-2")
    t0 = time.perf_counter()
    _, details = diagnose(s1, s2, same=False)
    accepted = details["accepted"]
    print("effects diagnosed on session-2: " + ", ".join(
        f"{c.effect}[{c.sensor}] {c.params}" for c in accepted))
    settings = ForestSettings(n_estimators=args.trees, seed=args.seed)
    site = resolve_site_map("auto", s1.rig)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        aug = load_session(write_session(tmp / "training-data", s1.rig, s1.x_mm, s1.y_mm, s1.height_mm,
                                         augment(s1, accepted, details["ref"], args.seed), s1.case_id,
                                         s1.repetition))
        print(f"on session-2 ({len(s2)} drops), models trained on session-1 split {args.seed}, {args.trees} trees")
        print(HEADER)
        scores = {}
        for name, m in (("site map none", None), ("twin", site)):
            for which, sess in (("session-1 model", s1), ("retrained", aug)):
                out = tmp / f"{which}-{name}".replace(" ", "_") if args.board and m is not None else None
                model, _ = train(sess, out, 0.2, args.seed, settings=settings, site_map=m)
                scores[which, name] = score(s2, model)
                print(row(f"{which}, {name}", scores[which, name]), flush=True)
        print(f"({time.perf_counter() - t0:.0f} s)")
        if args.board:
            print("emulated board (4 x 50 kHz, firmware app, exported tables, 10 trees), session-2:")
            for which in ("session-1 model", "retrained"):
                m, out = tmp / f"{which}-twin".replace(" ", "_"), tmp / f"export-{which}".replace(" ", "_")
                out.mkdir()
                if (MODELS / "board-site-map.npz").is_file():   # the board-rate site map's cache
                    (out / "board-site-map.npz").write_bytes((MODELS / "board-site-map.npz").read_bytes())
                subprocess.run([sys.executable, "-m", "impactsense.cli", "export", str(m), "--out", str(out),
                                "--trees", "10", "--no-m2cgen"], check=True, stdout=subprocess.DEVNULL)
                v = board_score(out, s2)
                print(row(f"{which}, twin ({v['reported']} reported)", v), flush=True)
    # targets: retraining helps (the twin's and the forests' MAE fall), and the retrained twin model stays
    # within 1.15x of the 2.22 mm measured when it landed (docs/findings.md); 1.3x misses
    before, after = scores["session-1 model", "twin"], scores["retrained", "twin"]
    ok = (after["mae_mm"] < before["mae_mm"] and after["mae_mm"] <= 2.55
          and scores["retrained", "site map none"]["mae_mm"] < scores["session-1 model", "site map none"]["mae_mm"])
    print("targets (retrained twin MAE < the session-1 model's and <= 2.55 mm; forests' MAE falls): "
          + ("met" if ok else "MISSED"))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
