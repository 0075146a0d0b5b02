"""The board's per-event cost on the rig's own drops (issue 15): the slowest of the drops the model was made from,
each drop's parts predicted on the host from what the same C++ does on the same board captures.

board.cost's constant form adds each part's worst case (the features' and report's, the localiser's at its
evaluation cap, each tree's deepest walk); the parts' slowest drops differ, so that sum lies above every measured
event by 3-30 % (docs/findings.md "Session 26: exportest"). Here each drop is priced whole: the host core (its
build counts impactcore.h WorkCounts) runs the board's captures of the session's drops and gives each one's work
counters and localiser evaluations (both equal to the board's: the same code on the same captures), the forests'
walks are counted on its feature vector (board.cost.forest_nodes), and

  drop = FEATURES_FIXED (a forest or a twin model's) + sum_k FEATURES_PER_COUNT[k] x counter_k
         + the bond inverse + the band picks + (LOCALISER_SCREEN + evaluations x LOCALISER_PER_EVALUATION)
         + the channel check + the forests' walk of this drop + the twin's match (its bound);

the slowest drop is what to expect on the board. The rates are a bound at or above every drop of the qemu runs they
were fitted on; fitted without one run, they stay above that run's slowest drop on every hum-free run (+2.0k..+7.6k)
and fall below it on the one run whose slowest drop models a hum (-4.1k): the hum's cost per channel is the rate the
runs do not agree on (docs/findings.md "Session 26: exportest"). So export's estimate (export_check.estimate_total)
is this on a session without hum, and the larger of this and the parts' worst cases on a session whose drops model a
hum or redo a channel (any_hum, beyond_base).
"""

from __future__ import annotations

import numpy as np

from .. import _core
from ..pipeline import as_int16
from ..signal import SignalConfig
from . import cost
from .capture import board_captures

HUM_CHANNELS_IN_BASE = 1   # board.cost's BASE_INSTRUCTIONS covers a drop with one channel's mains hum modelled


def drop_counts(models, n_trees: dict, session, fs_hz: int = 50000) -> dict:
    """What the host core does on the board's captures of every drop of `session`: 'work' [R, K] with 'fields',
    'evaluations' [R] (every start's), 'walk' [R] (nodes the localisation forests' prefixes n_trees visit), 'rows'."""
    caps, rows, cfg = board_captures(session, int(fs_hz), models.signal)
    out = _core.process_batch(as_int16(caps, cfg), cfg.core(), cfg.localiser())
    X = np.asarray(out["vector"], dtype=np.float32)
    walk = np.zeros(len(X), dtype=np.int64)
    for role, forest in (("x", models.x), ("y", models.y)):
        k = int(n_trees[role])
        if k > 0:
            walk += cost.forest_nodes(forest, X[:, models.inputs[role]])[:k].sum(axis=0)
    return {"work": np.asarray(out["work"], dtype=float), "fields": [str(f) for f in out["work_fields"]],
            "evaluations": np.asarray(out["localiser_evaluations"])[:, 0].astype(np.int64), "walk": walk,
            "rows": np.asarray(rows)}


def features_instructions(counts: dict, twin: bool) -> np.ndarray:
    """The features and report per drop (without the bond inverse): FEATURES_FIXED + the counters' rates + the
    report's share of a forest or a twin model."""
    rates = np.array([cost.FEATURES_PER_COUNT.get(str(f), 0.0) for f in counts["fields"]])
    return cost.FEATURES_FIXED["twin" if twin else "forests"] + np.asarray(counts["work"], dtype=float) @ rates


def forests_fixed(walks: dict, trees: dict, inputs: dict, linear_terms: int = 0) -> int:
    """The models' cost on every drop beside the localisation forests' walk: FOREST_FIXED, the inputs' keys, the
    energy class (linear_terms of the linear estimate, or the class forest's prefix trees['energy'] at its trees'
    deepest walks walks['energy']); walks / trees / inputs as board.cost.event_parts takes them."""
    keys = sum(int(inputs.get(r, 0)) for r in ("x", "y") if int(trees.get(r, 0)) > 0)
    energy = cost.linear_instructions(linear_terms)
    k = int(trees.get("energy", 0)) if "energy" in walks else 0
    if k > 0:
        energy += (cost.FOREST_PER_NODE * int(np.sum(walks["energy"][:k])) + cost.FOREST_PER_INPUT
                   * int(inputs.get("energy", 0)) + cost.CLASS_FOREST_FIXED)
    return cost.FOREST_FIXED + cost.FOREST_PER_INPUT * keys + energy


def model_inputs(models, n_trees: dict) -> dict:
    """What event_parts and forests_fixed read of an export: walks (each tree's deepest path), trees, inputs,
    linear_terms."""
    roles = {"x": models.x, "y": models.y} if models.energy_linear else {
        "x": models.x, "y": models.y, "energy": models.energy}
    return {"walks": {r: cost.deepest_walks(f)[:, 0].tolist() for r, f in roles.items()},
            "trees": {r: int(n_trees[r]) for r in roles}, "inputs": {r: len(v) for r, v in models.inputs.items()},
            "linear_terms": models.energy_trees() if models.energy_linear else 0}


def drop_instructions(counts: dict, parts: dict, cfg, twin: bool, fixed_models: int) -> np.ndarray:
    """Each drop's event (instructions): the features and report from its counters (a twin model's or not), the
    constant parts of `parts` (board.cost.event_parts: the band picks, the channel check, the twin's match), the
    bond inverse's bound, its localiser at its own evaluations (signal configuration cfg) and its forests' walk on
    top of fixed_models (forests_fixed)."""
    k = 0 if cost.isotropic((cfg.travel_metric_xx, cfg.travel_metric_xy, cfg.travel_metric_yy)) else 1
    loc = cost.LOCALISER_SCREEN[k] + np.asarray(counts["evaluations"]) * cost.LOCALISER_PER_EVALUATION[k]
    if parts["band"]:   # the band picks' own localiser run: its bound, as in the constant form
        loc = loc + cost.localiser_run_instructions(max(1, int(cfg.localiser_starts)), k == 0,
                                                    cost.evaluations_cap(cfg))
    bond = cost.BOND_PER_SAMPLE * cost.bond_samples(cfg)
    walk = cost.FOREST_PER_NODE * np.asarray(counts["walk"])
    return (features_instructions(counts, twin) + bond + parts["band"] + loc + parts["check"] + fixed_models + walk
            + parts["twin"])


def rig_estimate(models, n_trees: dict, parts: dict, session, fs_hz: int = 50000) -> dict:
    """What to expect on the session's drops (slowest)."""
    counts = drop_counts(models, n_trees, session, fs_hz)
    per = drop_instructions(counts, parts, SignalConfig.from_dict(models.signal), models.twin is not None,
                            forests_fixed(**model_inputs(models, n_trees)))
    return slowest(per, parts, counts["rows"], beyond_base(counts), any_hum(counts))


def beyond_base(counts: dict) -> bool:
    """Whether some drop does more than BASE_INSTRUCTIONS covers: a mains hum modelled on more than one channel, or a
    channel passed again (a spike found and the channel redone) (impactcore.h WorkCounts)."""
    w = np.asarray(counts["work"])
    fields = list(counts["fields"])
    col = lambda name: w[:, fields.index(name)] if len(w) else np.zeros(0)  # noqa: E731
    return bool(np.any(col("hum_channels") > HUM_CHANNELS_IN_BASE) or np.any(col("channel_passes") > 4))


def any_hum(counts: dict) -> bool:
    """Whether the core modelled a mains hum on some channel of some drop (WorkCounts hum_channels)."""
    w = np.asarray(counts["work"])
    return bool(len(w) and np.any(w[:, list(counts["fields"]).index("hum_channels")] > 0))


def slowest(per: np.ndarray, parts: dict, rows, beyond: bool = False, hum: bool = False) -> dict:
    """{'slowest' (instructions), 'row', 'drops', 'beyond_base', 'hum' and, where `parts` has one, 'flagged': the
    slowest drop with the flagged path's cost (parts' 'flagged' less its 'total') in place of the clean one's}."""
    i = int(np.argmax(per))
    out = {"slowest": int(np.ceil(per[i])), "row": int(np.asarray(rows)[i]), "drops": int(len(per)),
           "beyond_base": bool(beyond), "hum": bool(hum)}
    if "flagged" in parts:
        out["flagged"] = out["slowest"] + int(parts["flagged"]) - int(parts["total"])
    return out
