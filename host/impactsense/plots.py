"""Figures: predicted vs true (the seed's Fig. 11) and an error map over the plate."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402



def predicted_vs_true(true_xy, pred_xy, path, title="") -> Path:
    fig, axes = plt.subplots(1, 2, figsize=(9, 4.4))
    for k, (ax, name) in enumerate(zip(axes, ("x", "y"))):
        ax.scatter(true_xy[:, k], pred_xy[:, k], s=10, alpha=0.7)
        lo, hi = 0, max(320, float(np.nanmax(true_xy[:, k])))
        ax.plot([lo, hi], [lo, hi], "k--", lw=1)
        ax.set_xlabel(f"true {name} (mm)")
        ax.set_ylabel(f"predicted {name} (mm)")
        ax.set_aspect("equal")
        ax.grid(alpha=0.3)
    fig.suptitle(title or "predicted vs true")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def error_map(true_xy, pred_xy, sensor_xy, plate_mm, path, title="", inner_region=None) -> Path:
    err = np.hypot(*(pred_xy - true_xy).T)
    fig, ax = plt.subplots(figsize=(6, 5.6))
    sc = ax.scatter(true_xy[:, 0], true_xy[:, 1], c=err, cmap="viridis", s=28,
                    vmin=0, vmax=max(5.0, float(np.nanpercentile(err, 95))))
    ax.quiver(true_xy[:, 0], true_xy[:, 1], pred_xy[:, 0] - true_xy[:, 0], pred_xy[:, 1] - true_xy[:, 1],
              angles="xy", scale_units="xy", scale=1, width=0.003, color="r", alpha=0.6)
    ax.scatter(sensor_xy[:, 0], sensor_xy[:, 1], marker="s", s=80, c="k", label="sensors")
    if inner_region is not None:
        x0, x1, y0, y1 = inner_region
        ax.add_patch(plt.Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ls="--", ec="grey", label="inner region"))
    ax.set_xlim(0, plate_mm[0])
    ax.set_ylim(0, plate_mm[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    fig.colorbar(sc, ax=ax, label="error (mm)")
    ax.legend(loc="upper center", fontsize=8, ncol=2)
    ax.set_title(title or "localisation error (arrows: true -> predicted)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def evaluation_plots(report: dict, rig, out_dir, label="model") -> list[Path]:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    a = report["_arrays"]
    ok = np.isfinite(a["pred_xy"]).all(1)
    plate = (rig.plate_x_mm, rig.plate_y_mm)
    return [
        predicted_vs_true(a["true_xy"][ok], a["pred_xy"][ok], out / f"{label}_pred_vs_true.png",
                          f"{label}: MAE {report['all']['mae_mm']:.2f} mm"),
        error_map(a["true_xy"][ok], a["pred_xy"][ok], rig.sensor_xy_mm, plate, out / f"{label}_error_map.png",
                  inner_region=rig.inner_region_mm),
        error_map(a["true_xy"][ok], a["phys_xy"][ok], rig.sensor_xy_mm, plate, out / "physics_error_map.png",
                  "physics localiser error", inner_region=rig.inner_region_mm),
    ]
