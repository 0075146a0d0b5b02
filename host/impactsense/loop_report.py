"""The evidence of one `diagnose` a person reads: summary.md, the figures, and report.html (self-contained:
the matplotlib PNGs are embedded) with the residual maps before/after, the effect table with 95 % intervals,
the rivals and candidates tried and rejected, the physics before/after and, when the loop was closed
(`impactsense retrain`, benchmarks/bench_loop.py), the models' MAE before/after on the new session's labels.
"""

from __future__ import annotations

import base64
import html
import json
from pathlib import Path

import numpy as np

from . import residuals as R


def _figures(F, ref, final, out: Path) -> list[Path]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    for tag, m in (("before", ref), ("after", final)):
        pred = m.toa_pred(F)
        r = (F.toa_us[:, R.PAIR_I] - F.toa_us[:, R.PAIR_J]) - (pred[:, R.PAIR_I] - pred[:, R.PAIR_J])
        fig, axes = plt.subplots(2, 3, figsize=(12, 7.5), constrained_layout=True)
        lim = max(float(np.nanpercentile(np.abs(r), 95)), 1e-3)
        for p, ax in enumerate(axes.ravel()):
            sc = ax.scatter(F.x_mm, F.y_mm, c=r[:, p], cmap="coolwarm", vmin=-lim, vmax=lim, s=12)
            ax.set_title(f"DToA S{R.PAIR_I[p] + 1}-S{R.PAIR_J[p] + 1}: mean {np.nanmean(r[:, p]):+.1f} µs")
            ax.set_aspect("equal")
            ax.plot(m.sensor_xy_mm[:, 0], m.sensor_xy_mm[:, 1], "k^")
        fig.colorbar(sc, ax=axes, label="measured - predicted DToA (µs)")
        paths.append(out / f"dtoa_residual_map_{tag}.png")
        fig.savefig(paths[-1], dpi=72)
        plt.close(fig)
        d, *_ = m.geometry(F)
        rt, re = m.toa_resid(F), np.where(m.clip_mask(F), np.nan, m.energy_resid(F))
        fig, axes = plt.subplots(1, 3, figsize=(15, 4.5), constrained_layout=True)
        for c in range(4):
            axes[0].plot(d[:, c], rt[:, c], ".", ms=3, label=f"S{c + 1}")
            axes[1].hist(rt[:, c], bins=40, histtype="step", label=f"S{c + 1} mean {np.nanmean(rt[:, c]):+.2f}")
            axes[2].plot(d[:, c], re[:, c], ".", ms=3, label=f"S{c + 1}")
        axes[0].set_xlabel("distance (mm)")
        axes[0].set_ylabel("ToA residual, drop-centred (µs)")
        axes[1].set_xlabel("ToA residual (µs)")
        axes[2].set_xlabel("distance (mm)")
        axes[2].set_ylabel("log-energy residual, drop-centred")
        for ax in axes:
            ax.legend(fontsize=8)
        paths.append(out / f"toa_residual_vs_distance_{tag}.png")
        fig.savefig(paths[-1], dpi=72)
        plt.close(fig)
    return paths


def _fmt_params(e: dict) -> str:
    ci = e.get("param_ci95") or {}
    cells = []
    for k, v in e["params"].items():
        if not isinstance(v, (int, float)):
            continue
        cells.append(f"{k}={v:.4g}" + (f" [{ci[k][0]:.4g}, {ci[k][1]:.4g}]" if k in ci else ""))
    return ", ".join(cells)


def _sensor(e: dict) -> str:
    return "-" if e["sensor"] is None else f"S{e['sensor'] + 1} (ch{e['sensor']})"


def _rival(e: dict) -> str:
    rv = e.get("rival")
    if not rv:
        return ""
    text = f"vs {rv['effect']}: {rv['score_difference']:+.1f} nats held out (p {rv['p_value']:.2g})"
    if "direction_p_value" in rv:   # the move-or-delay test (effects.sensor_position.direction_test)
        text += f"; direction dependence p {rv['direction_p_value']:.2g}"
        if "band_p_value" in rv:   # ... and the band picks' shift against the threshold picks' (band_test)
            text += f", band picks p {rv['band_p_value']:.2g}"
        if "joint_p_value" in rv:   # ... and both pick sets in one regression (joint_test)
            text += f", both pick sets p {rv['joint_p_value']:.2g}"
        if rv.get("ambiguous"):
            text += ": a move along the disc's look direction would read the same (ambiguous)"
    return text


def _levels(picker: dict) -> str:
    """A timing picker's onset threshold, or its thresholds whose picks are averaged ("10 + 20")."""
    return " + ".join(f"{v:g}" for v in picker.get("onset_threshold_levels") or [picker["onset_threshold_counts"]])


def summary_lines(result: dict) -> list[str]:
    lines = ["# impactsense diagnose", "", f"- baseline: {result['baseline']}", f"- data: {result['data']}",
             f"- reference: {result['reference']}", "",
             "| effect | sensor | params [95 % interval] | score (nats) | significant | rival |",
             "|---|---|---|---|---|---|"]
    for e in result["effects"]:
        lines.append(f"| {e['effect']} | {_sensor(e)} | {_fmt_params(e)} | {e['score']:.1f} | "
                     f"{e['significant']} | {_rival(e)} |")
    lines += ["", "| metric | before | after |", "|---|---|---|"]
    for k in ("dtoa_rms_us", "mae_mm", "energy_rms"):
        lines.append(f"| {k} | {result['before'][k]:.3f} | {result['after'][k]:.3f} |")
    res = result.get("residuals", {})
    if res:
        lines += ["", "Residual dependence before the effects (slope per 1 SD of the regressor, µs; |t| > 3 in bold):",
                  "", "| channel | " + " | ".join(res["dependence_before"]["regressors"]) + " |",
                  "|---" * 7 + "|"]
        for c, row in enumerate(res["dependence_before"]["toa_us"]):
            cells = [(f"**{b:+.2f}**" if abs(b) > 3 * se else f"{b:+.2f}") for b, se in zip(row["slope"], row["se"])]
            lines.append(f"| S{c + 1} ToA | " + " | ".join(cells) + " |")
        rep = res["repeatability"]["dtoa_within_case_rms_us"]
        lines += ["", "DToA within-case repeatability (µs rms, pairs 01 02 03 12 13 23): "
                      + " ".join(f"{v:.1f}" for v in rep),
                  "noise floor (counts rms): " + " ".join(f"{v:.2f}" for v in res["noise_rms_counts"]),
                  "hum 50/60 Hz (counts): " + " ".join(f"{a:.2f}/{b:.2f}" for a, b in res["hum_counts_50_60hz"]),
                  f"clipped drops per channel: {res['clipped_drops']}"]
    trials = result.get("timing_picker_trials") or []
    if trials:
        lines += ["", "Timing picks tried on the baseline (held-out DToA of its reference, µs; "
                      f"chosen: {json.dumps(result.get('timing_picker')) if result.get('timing_picker') else 'the AIC onset'}):",
                  "", "| onset threshold (a + b: their picks' mean) | AIC blend | dispersion exponent | "
                      "held-out DToA µs |",
                  "|---|---|---|---|"]
        lines += [f"| {_levels(t)} | {t['aic_blend']:.2f} | {t.get('dispersion_exponent', 0.0):.3f} | "
                  f"{t['heldout_dtoa_us']:.2f} |" for t in trials]
    lines += ["", f"core_config: {json.dumps(result['core_config'])}", "",
              "Figures: dtoa_residual_map_{before,after}.png, toa_residual_vs_distance_{before,after}.png"]
    return lines


def _table(head: list[str], rows: list[list[str]]) -> str:
    h = "".join(f"<th>{html.escape(c)}</th>" for c in head)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><tr>{h}</tr>{body}</table>"


def _loop_table(loop: dict) -> str:
    """loop: {"rows": {label: {"mae_mm":..., "inner_mae_mm":..., "energy_class_accuracy":...}}, "note": str}"""
    rows = [[k, f"{v.get('mae_mm', float('nan')):.2f}", f"{v.get('inner_mae_mm', float('nan')):.2f}",
             f"{v.get('energy_class_accuracy', float('nan')):.3f}"] for k, v in loop.get("rows", {}).items()]
    return (_table(["model", "MAE mm (whole plate)", "MAE mm (inner)", "class accuracy"], rows)
            + f"<p>{html.escape(loop.get('note', ''))}</p>")


def html_report(result: dict, figures: list[Path], loop: dict | None = None) -> str:
    sig = [e for e in result["effects"] if e["significant"]]
    rej = [e for e in result["effects"] if not e["significant"] and e["effect"] != "none"]
    named = [[e["effect"], _sensor(e), _fmt_params(e), f"{e['score']:.1f}", f"{e.get('p_value', 1):.2g}", _rival(e)]
             for e in sig] or [["none", "-", "", "", "", ""]]
    tried = [[e["effect"], _sensor(e), _fmt_params(e), f"{e['score']:.1f}", f"{e.get('p_value', 1):.2g}"] for e in rej]
    tried += [[e["rival"]["effect"], _sensor(e), "rival of the named " + e["effect"],
               f"{-e['rival']['score_difference']:+.1f} vs it", ""] for e in sig if e.get("rival")]
    metrics = [[k, f"{result['before'][k]:.3f}", f"{result['after'][k]:.3f}"]
               for k in ("dtoa_rms_us", "mae_mm", "energy_rms")]
    imgs = "".join(f"<h3>{html.escape(p.stem)}</h3><img src='data:image/png;base64,"
                   f"{base64.b64encode(p.read_bytes()).decode()}'/>" for p in figures)
    parts = ["<!doctype html><html><head><meta charset='utf-8'><title>impactsense diagnose</title>",
             "<style>body{font-family:sans-serif;max-width:1250px;margin:auto}table{border-collapse:collapse}"
             "td,th{border:1px solid #aaa;padding:3px 8px;font-size:13px}img{max-width:100%}</style></head><body>",
             "<h1>impactsense diagnose</h1>",
             f"<p>baseline {html.escape(result['baseline'])}<br>data {html.escape(result['data'])}<br>"
             f"reference: {html.escape(result['reference'])}</p>",
             "<h2>Named effects (95 % intervals: jackknife over the case folds)</h2>",
             _table(["effect", "sensor", "params [95 %]", "held-out gain (nats)", "p", "rival"], named),
             "<h2>Physics reference before / after the effects (held-out folds)</h2>",
             _table(["metric", "before", "after"], metrics)]
    if loop:
        parts += ["<h2>Models before / after the loop, on the new session's labels</h2>", _loop_table(loop)]
    parts += ["<h2>Tried and rejected</h2>",
              _table(["effect", "sensor", "params", "held-out gain (nats)", "p"], tried),
              "<h2>Residuals before / after</h2>", imgs, "<h2>Details</h2><pre>",
              html.escape("\n".join(summary_lines(result))), "</pre></body></html>"]
    return "".join(parts)


def write_report(result: dict, details: dict, out_dir: str | Path, loop: dict | None = None) -> Path:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    figs = _figures(details["F"], details["ref"], details["final"], out)
    (out / "summary.md").write_text("\n".join(summary_lines(result)) + "\n")
    (out / "report.html").write_text(html_report(result, figs, loop))
    return out
