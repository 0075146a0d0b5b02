"""impactsense retrain --baseline DATA_REF --data DATA_NEW --out MODEL_DIR"""

from __future__ import annotations

import json
import tempfile
from dataclasses import replace
from pathlib import Path

ORDER = 51


def register(sub) -> None:
    p = sub.add_parser(
        "retrain", help="retrain for a changed rig: add the diagnosed effects to the training data",
        description="Diagnoses DATA_NEW against DATA_REF, puts the significant effects into DATA_REF's "
                    "recordings (each effect's own signal model: delay, gain, low-pass, speed, ...), "
                    "trains the standard model on that and evaluates it on DATA_NEW beside a model "
                    "trained on DATA_REF as it is.")
    p.add_argument("--baseline", required=True, help="reference session folder (or 'bundled')")
    p.add_argument("--data", required=True, help="the changed session")
    p.add_argument("--out", required=True, help="model folder to write")
    p.add_argument("--test-fraction", type=float, default=0.2, help="cases of DATA_REF held out (default 0.2)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--trees", type=int, default=100)
    p.set_defaults(func=run)


def augment(base, accepted, ref, seed: int = 0):
    """DATA_REF's recordings with the diagnosed effects put in (uint16, same shape)."""
    from ..effects import context
    from ..effects.apply import apply_effects

    effects = [{"effect": c.effect, "sensor": c.sensor, "params": c.params} for c in accepted]
    return apply_effects(base.adc, effects, context(base, ref.slowness_us_per_mm), seed)


def run(args) -> int:
    import numpy as np

    from ..data import load_session, resolve_session_path, write_session
    from ..diagnose import diagnose
    from ..errors import ConfigError
    from ..models import ForestSettings
    try:
        from ..workflow import evaluate, train
    except ImportError as exc:  # the training API is the lead's
        raise ConfigError(f"retrain needs impactsense.workflow (train/evaluate): {exc}") from None

    if not 0.0 <= args.test_fraction < 1.0:
        raise ConfigError(f"--test-fraction must be in [0, 1), got {args.test_fraction}")
    base = load_session(args.baseline)
    same = resolve_session_path(args.baseline).resolve() == resolve_session_path(args.data).resolve()
    data = base if same else load_session(args.data)
    result, details = diagnose(base, data, same=same)
    accepted = [] if same else details["accepted"]
    settings = ForestSettings(n_estimators=args.trees, seed=args.seed)
    card = {"diagnose": {k: result[k] for k in ("effects", "before", "after", "reference")},
            "retrain": {"baseline": str(base.path), "data": str(data.path),
                        "effects_added": [{"effect": c.effect, "sensor": c.sensor, "params": c.params}
                                          for c in accepted]}}
    out = Path(args.out)
    rows = {}
    plain, _ = train(base, None, args.test_fraction, args.seed, settings=settings)
    rows["baseline model"] = evaluate(data, plain, np.arange(len(data)))
    if accepted:
        adc = augment(base, accepted, details["ref"], args.seed)
        with tempfile.TemporaryDirectory() as tmp:
            path = write_session(Path(tmp) / f"{base.name}+effects", base.rig, base.x_mm, base.y_mm,
                                 base.height_mm, adc, base.case_id, base.repetition)
            aug = load_session(path)
            model, _ = train(aug, out, args.test_fraction, args.seed, settings=settings, extra_card=card)
    else:
        model, _ = train(base, out, args.test_fraction, args.seed, settings=settings, extra_card=card)
    rows["retrained model"] = evaluate(data, model, np.arange(len(data)))
    summary = {k: {"mae_mm": v["all"]["mae_mm"], "rmse_mm": v["all"]["rmse_mm"],
                   "physics_mae_mm": v["physics"]["all"]["mae_mm"],
                   "energy_class_accuracy": v["energy_class_accuracy"]} for k, v in rows.items()}
    (out / "retrain.json").write_text(json.dumps({**card, "on_data": summary}, indent=1))
    print("effects added: " + (", ".join(f"{c.effect}[{c.sensor}]" for c in accepted) or "none"))
    print(f"{'on ' + data.name:<18} {'MAE mm':>8} {'RMSE mm':>8} {'phys MAE':>9} {'class acc':>9}")
    for k, v in summary.items():
        print(f"{k:<18} {v['mae_mm']:8.2f} {v['rmse_mm']:8.2f} {v['physics_mae_mm']:9.2f} "
              f"{v['energy_class_accuracy']:9.3f}")
    print(f"model written to {out}")
    return 0
