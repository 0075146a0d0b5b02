"""A bond the retrained model may not absorb: the four-channel model (the bond's low-pass and gain put into the
training drops) against the same drops trained with the bond's channel left out (the core's channel_left_out:
three-sensor picks, travel fit and forests; its reports flag the channel), chosen on DATA_NEW's own labelled drops.

No label-free figure tells which of the two places a bonded session better (docs/findings.md, "Training with a
channel left out" and "A debonded channel on a model without a twin"); the loop's new session is labelled (diagnose
reads it at its declared positions), so the choice is made there, the way retrain already judges its model against
the baseline's (`retrain.worse_than_baseline`). A choice on the same drops it is scored on is optimistic; the
cross-fitted figure is the honest one: each half of DATA_NEW's cases placed by the model the other half chose.

A third candidate, when given: the reference model as it would serve DATA_NEW (untouched: its check flags the
bond channel and it takes its three-sensor path), scored by the same rule on the same drops; on some draws it
places a strong bond's session better than either retrained model (docs/findings.md, issue 16, bondpick/bondref)."""

from __future__ import annotations

from .model_choice import choose_model

CHOICES = ("four", "left_out", "reference")


def choose_left_out(four_model, left_out_model, data, channel: int, seed: int = 0, reference_model=None) -> dict:
    """Which model to keep ("four", "left_out" or, when reference_model is given, "reference": the lowest MAE per
    axis on DATA_NEW's drops; `model_choice.choose_model`) with each candidate's MAE and the cross-fitted MAE of the
    rule (DATA_NEW's cases in two seeded halves; each half placed by the model the other half chose)."""
    got = choose_model({"four": four_model, "left_out": left_out_model, "reference": reference_model}, data, seed)
    out = {"channel": int(channel), "chosen": got["chosen"], "four_mae_mm": got["mae_mm"]["four"],
           "left_out_mae_mm": got["mae_mm"]["left_out"], "cross_fitted_mae_mm": got["cross_fitted_mae_mm"]}
    if "reference" in got["mae_mm"]:
        out["reference_mae_mm"] = got["mae_mm"]["reference"]
    return out


def fit_with_bond_choice(fit, signal, data, accepted, *, site_map=None, left_out=(), seed: int = 0, reference=None):
    """(fit(signal)'s result, the choice or None). fit trains on the training drops with a signal config and
    returns (model, ...). With one bond channel put in (loop.weak_channel), no channel left out already and no site
    map (with one, the twin matches with and without the weak channel and flags it: twin.h weak_channel), the same
    drops are also fitted with that channel left out, and the one `choose_left_out` keeps is returned; `reference`
    (the reference model's (model, ...), as it serves DATA_NEW) is the third candidate, returned when it is kept."""
    from .commands.retrain import leave_out
    from .loop import weak_channel

    channel = weak_channel(accepted)
    four = fit(signal)
    if channel < 0 or site_map is not None or len(left_out):
        return four, None
    three = fit(leave_out(signal, [channel]))
    choice = choose_left_out(four[0], three[0], data, channel, seed,
                             reference_model=None if reference is None else reference[0])
    return {"four": four, "left_out": three, "reference": reference}[choice["chosen"]], choice
