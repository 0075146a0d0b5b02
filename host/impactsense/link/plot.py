"""A live plot of the plate for `impactsense monitor --plot`: the plate outline, the four sensors, the last N
reported impacts coloured by energy class and a circle of the latest report's uncertainty (the report's
uncertainty_mm is the localiser's sqrt(var_x + var_y), so the covariance ellipse it summarises is drawn as a
circle of that radius).

The plot only draws: the monitor feeds it reports and calls `refresh()` between serial reads (the reads run
in their own thread, link.monitor), so a slow redraw never stalls the port. `open_live_plot` returns None,
with a message, when there is no display to draw on.
"""

from __future__ import annotations

import math
import os
import sys
from collections import deque

import numpy as np

CLASS_COLOURS = {0: "tab:blue", 1: "tab:red"}   # energy class 0 = low, 1 = high
UNKNOWN_COLOUR = "tab:gray"                     # no valid class (energy_class -1)


class LivePlot:
    """Draws reports on a matplotlib figure (interactive window or, for tests and files, any canvas)."""

    def __init__(self, fig, plate_mm: tuple[float, float], sensors_mm, last_n: int = 20):
        from matplotlib.patches import Circle, Rectangle

        self.fig = fig
        self.last = deque(maxlen=int(last_n))
        ax = self.ax = fig.add_subplot(1, 1, 1)
        px, py = (float(v) for v in plate_mm)
        ax.add_patch(Rectangle((0, 0), px, py, fill=False, lw=1.5, color="k"))
        s = np.asarray(sensors_mm, float).reshape(-1, 2)
        self.sensors = ax.scatter(s[:, 0], s[:, 1], marker="s", s=60, c="k", label="sensors")
        for k, (x, y) in enumerate(s):
            ax.annotate(f"S{k + 1}", (x, y), textcoords="offset points", xytext=(6, 6))
        self.points = ax.scatter(np.empty(0), np.empty(0), s=40, zorder=3)
        self.uncertainty = Circle((0, 0), 0.0, fill=False, ls="--", color="k", visible=False, zorder=2)
        ax.add_patch(self.uncertainty)
        ax.scatter([], [], c=CLASS_COLOURS[0], label="low energy")
        ax.scatter([], [], c=CLASS_COLOURS[1], label="high energy")
        ax.legend(loc="upper right", fontsize="small", framealpha=0.8)
        m = 0.05 * max(px, py)
        ax.set_xlim(-m, px + m)
        ax.set_ylim(-m, py + m)
        ax.set_aspect("equal")
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        self.title = ax.set_title("waiting for impacts")
        self.dirty = False

    def add(self, report: dict) -> None:
        """Adds one report (a decoded report dict); reports without a valid position are not drawn."""
        x, y = report.get("x_mm"), report.get("y_mm")
        if not report.get("valid", True) or x is None or y is None or not (math.isfinite(x) and math.isfinite(y)):
            return
        self.last.append(report)
        xy = np.array([[r["x_mm"], r["y_mm"]] for r in self.last], float)
        self.points.set_offsets(xy)
        self.points.set_facecolors([CLASS_COLOURS.get(r.get("energy_class"), UNKNOWN_COLOUR) for r in self.last])
        u = report.get("uncertainty_mm")
        ok = u is not None and math.isfinite(u) and u > 0
        self.uncertainty.set_center((x, y))
        self.uncertainty.set_radius(float(u) if ok else 0.0)
        self.uncertainty.set_visible(bool(ok))
        acc = "accepted" if report.get("accepted") else "rejected (Eq. 35)"
        unc = f" ± {u:.1f} mm" if ok else ""
        self.title.set_text(f"#{report.get('seq')}: ({x:.1f}, {y:.1f}) mm{unc}, {acc}")
        self.dirty = True

    def refresh(self) -> bool:
        """Redraws if something changed; False once the window has been closed."""
        canvas = self.fig.canvas
        manager = getattr(canvas, "manager", None)
        if manager is not None:
            import matplotlib.pyplot as plt

            if not plt.fignum_exists(manager.num):
                return False
        if self.dirty:
            canvas.draw_idle() if manager is not None else canvas.draw()
            self.dirty = False
        if manager is not None:
            canvas.flush_events()
        return True


def _interactive_backends() -> list[str]:
    try:  # matplotlib >= 3.9
        from matplotlib.backends import BackendFilter, backend_registry

        return backend_registry.list_builtin(BackendFilter.INTERACTIVE)
    except ImportError:
        from matplotlib import rcsetup

        return [b.lower() for b in rcsetup.interactive_bk]


def display_problem() -> str | None:
    """Why no window can be opened here, or None."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return "no display (neither DISPLAY nor WAYLAND_DISPLAY is set)"
    return None


def open_live_plot(plate_mm, sensors_mm, last_n: int = 20, err=sys.stderr) -> LivePlot | None:
    """An interactive window with a LivePlot, or None (with a message on err) when none can be opened."""
    why = display_problem()
    if why is None:
        try:
            import matplotlib
            import matplotlib.pyplot as plt

            backend = matplotlib.get_backend().lower()
            if backend not in _interactive_backends():
                why = (f"matplotlib found no usable interactive backend (it fell back to {backend!r}): is the "
                       f"display reachable, and is a GUI toolkit installed (python3-tk)?")
            else:
                plt.ion()
                fig = plt.figure("impactsense monitor", figsize=(6.4, 6.4))
                plot = LivePlot(fig, plate_mm, sensors_mm, last_n)
                plt.show(block=False)
                plot.refresh()
                return plot
        except Exception as exc:  # noqa: BLE001  (a broken GUI toolkit: monitor without the plot)
            why = f"cannot open a plot window ({type(exc).__name__}: {exc})"
    print(f"monitor: --plot: {why}; continuing without the plot", file=err)
    return None
