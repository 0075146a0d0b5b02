"""What a measured session's calibrated twin does in its model: the reported position and the energy class, the
class only, or nothing (`train DATA --calibration CAL.json`; docs/method.md section 2, docs/findings.md "Session
21: rigcsite").

The twin's match places a drop from its 16 simulated log-energies on a 5 mm grid, and its height estimate reads
the drop's energies against the same map. Both are checked out of fold on the training drops (twin_oof: forests
and twin fitted on four position-grouped folds, the twin matched around the forests' position on the fifth):

- its **position and class** are kept when twin_oof.twin_choice keeps it (its out-of-fold MAE per axis not above
  the plain forest pair's, its class accuracy not below the measured classifier's by more than two standard
  errors of the paired difference) and its MAE is not above the out-of-fold MAE of the position the model without
  the twin reports (its members, correction factor and stack: the figure correction_scale / member_stack record
  in that model's card);
- else its **class** alone when its out-of-fold class accuracy beats the measured classifier's by more than
  CLASS_GAIN_SE standard errors of the paired difference (a twin that does not know the plate's site pattern
  classes about as well as the measured classifier: it must gain, not merely not lose).

With the class only, the reported position is the model without the twin's (every member, the three-sensor
path), and the class is the twin's height estimate matched around that position. Nothing names a rig: the rule
reads the training drops only.
"""

from __future__ import annotations

import math

CLASS_GAIN_SE = 1.0


def reported_oof_mae(card: dict) -> float:
    """The out-of-fold MAE per axis of the position a model without a site map reports, from its card: the members'
    stack's when kept, else the chosen correction factor's (after the level and field members' choices); NaN
    when the card has neither (a model with too few sites for the folds)."""
    stack = card.get("member_stack")
    if isinstance(stack, dict) and stack.get("keep"):
        return float(stack["out_of_fold_mae_mm"][1])
    scale = card.get("correction_scale")
    if isinstance(scale, dict) and "scales" in scale and "out_of_fold_mae_mm" in scale:
        return float(scale["out_of_fold_mae_mm"][list(scale["scales"]).index(scale["scale"])])
    return math.nan


def choose_twin_role(fit, args: tuple, site_map, **kwargs):
    """ImpactModel.fit with a site map and choose_twin: `fit` (the classmethod) is run with the twin (its
    out-of-fold figures in the card's twin_choice, the twin always kept) and without it; returns the model the
    rule above chooses, the card's "twin_choice" extended with "use_twin_class", "use_twin" (the position) and
    "reported_mae_mm" (the model without the twin's out-of-fold figure)."""
    with_twin = fit(*args, site_map=site_map, choose_twin="figures", **kwargs)
    plain = fit(*args, **kwargs)
    rec = dict(with_twin.card["twin_choice"])
    if "twin_mae_mm" not in rec:   # the twin matched no training drop out of fold
        plain.card["twin_choice"] = {**rec, "use_twin": False, "use_twin_class": False}
        return plain
    rec["reported_mae_mm"] = reported_oof_mae(plain.card)
    rec["use_twin"] = bool(rec["use_twin"] and not rec["twin_mae_mm"] > rec["reported_mae_mm"])  # NaN: the twin's
    gain = rec["twin_class_accuracy"] - rec["measured_class_accuracy"]
    rec["use_twin_class"] = bool(rec["use_twin"] or gain > CLASS_GAIN_SE * rec["class_difference_se"])
    if rec["use_twin"]:
        with_twin.card["twin_choice"] = rec
        return with_twin
    plain.card["twin_choice"] = rec
    if rec["use_twin_class"]:   # the twin's class on the model's own position
        plain.site_map, plain.twin_fit, plain.twin_position = with_twin.site_map, with_twin.twin_fit, False
        plain.forest_energy, plain.energy_threshold_j = with_twin.forest_energy, with_twin.energy_threshold_j
        plain.three_channel_class = {}
        plain.card.pop("energy_class_choice", None)
    return plain
