"""The public Python API (re-exported by `impactsense`): the steps of the command line as functions.

    import impactsense as isn
    s = isn.load_session()                           # bundled session-1 (or a folder, "bundled:session-2")
    model = isn.train(s, out="model")                # 80 % of the cases; the twin's site map for the bundled rig
    rep = isn.evaluate(model, s)                     # its held-out drops: rep["all"]["mae_mm"], ...
    pred = isn.predict(model, s.adc[:5])             # recordings [R, 4, samples] -> positions, classes
    isn.export_for_board("model", "out")           # C tables for the board (as `impactsense export`)
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .data import Session, load_session
from .models import ForestSettings, ImpactModel

__all__ = ["load_session", "load_model", "train", "predict", "evaluate", "export_for_board"]


def load_model(model_dir) -> ImpactModel:
    """A model folder written by `train` / `impactsense train`."""
    return ImpactModel.load(model_dir)


def train(session: Session, out=None, test_fraction: float = 0.2, seed: int = 0, trees: int = 100,
          site_map="auto", calibration=None, members: bool = True) -> ImpactModel:
    """Fits the physics localiser, the forests and (site_map "auto" on the bundled rig, or a site-map file) the
    twin's fingerprint on the training cases of `session`, holding out `test_fraction` of its cases (seeded);
    written to `out` (a model folder) if given. The model card (model.card) lists the split. calibration: a
    CAL.json of this rig (`impactsense calibrate`): with site_map "auto" its twin's site map, kept when the
    training drops' out-of-fold figures say so (as `impactsense train --calibration`). Without a site map the
    energy class is the classifier forest or the linear height estimate, as those figures choose (height_class.py).
    members False: one forest pair on the physics position, no position members (the band picks' or the edge
    correction's), which `export_for_board(..., rate=None)` takes as it is."""
    from .sitemap import resolve_site_map
    from .workflow import train as _train

    measured_twin = calibration is not None and site_map in (None, "auto")
    if measured_twin:
        from .chain import measured_site_map

        site = measured_site_map(session, calibration, progress=False)
    else:
        site = resolve_site_map(site_map, session.rig)
    model, _ = _train(session, out, test_fraction, seed, settings=ForestSettings(n_estimators=trees, seed=seed),
                      site_map=site, choose_twin=measured_twin, choose_class=True, members=members)
    return model


def predict(model: ImpactModel, recordings) -> dict:
    """Recordings (raw counts [R, 4, samples], or a Session) through the signal core and the model: a dict of
    arrays, `xy_mm` [R, 2] (NaN where the model gives no position), `energy_class` [R] (0 low, 1 high, -1
    none), `uncertainty_mm` [R] (1-sigma radial, with the twin), `accepted` [R] (Eq. 35) and the rest of
    ImpactModel.predict's keys."""
    adc = recordings.adc if isinstance(recordings, Session) else np.asarray(recordings)
    feats = model.featurize(adc)
    out = model.predict(feats)
    out["accepted"] = feats.accepted
    return out


def evaluate(model: ImpactModel, session: Session, rows=None) -> dict:
    """Scores the model on `session`: on its own training session only the held-out drops, on any other all
    drops (or the given rows). Keys as `impactsense evaluate`'s JSON: n, all / inner (r2, rmse_mm, mae_mm),
    energy_class_accuracy, physics, forest, ..."""
    from .workflow import evaluate as _evaluate
    from .workflow import public

    return public(_evaluate(session, model, None if rows is None else np.asarray(rows, int)))


def export_for_board(model_dir, out_dir, trees="auto", rate: int | None = 50000, m2cgen: bool = True) -> dict:
    """`impactsense export MODEL_DIR --out OUT_DIR`: the board's C tables (and m2cgen C), retrained at the
    board's rate first (rate None: the model's own forests); all of OUT_DIR or nothing. Returns export.json's
    summary."""
    from types import SimpleNamespace

    from .commands.export import _card, _export
    from .export import staged_output

    args = SimpleNamespace(model_dir=str(model_dir), trees=str(trees), no_m2cgen=not m2cgen)
    out = Path(out_dir)
    with staged_output(out) as stage:
        summary, _, _ = _export(args, _card(Path(model_dir)), rate, stage, out)
    return summary
