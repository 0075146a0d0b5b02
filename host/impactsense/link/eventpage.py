"""One self-contained HTML page of an event log (`impactsense events DB --html OUT.html`): the plate with its
sensors and the impacts, a heat map of the impacts, the energy classes over time and the link's health. The
figures are inline SVG (matplotlib), so the page needs nothing beside it."""

from __future__ import annotations

import html
import io
import time

import numpy as np

CLASS_COLOURS = {0: "tab:blue", 1: "tab:red"}
CLASS_NAMES = {0: "low", 1: "high"}


def _svg(fig) -> str:
    import matplotlib.pyplot as plt

    buf = io.StringIO()
    fig.savefig(buf, format="svg", bbox_inches="tight")
    plt.close(fig)
    text = buf.getvalue()
    return text[text.index("<svg"):]


def _plate(ax, rig) -> None:
    from matplotlib.patches import Rectangle

    ax.add_patch(Rectangle((0, 0), rig.plate_x_mm, rig.plate_y_mm, fill=False, lw=1.5, color="k"))
    ax.plot(rig.sensor_x_mm, rig.sensor_y_mm, "s", ms=9, color="tab:green", label="sensors")
    for k, (x, y) in enumerate(zip(rig.sensor_x_mm, rig.sensor_y_mm)):
        ax.annotate(f"S{k + 1}", (x, y), textcoords="offset points", xytext=(6, 6), fontsize=8)
    ax.set_xlim(-10, rig.plate_x_mm + 10)
    ax.set_ylim(-10, rig.plate_y_mm + 10)
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")


def plate_figure(reports: list[dict], rig) -> str:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 5.2))
    _plate(ax, rig)
    for cls, colour in CLASS_COLOURS.items():
        pts = [(r["x_mm"], r["y_mm"]) for r in reports if r["energy_class"] == cls and r["valid"] and r["x_mm"] is not None]
        if pts:
            ax.plot(*np.array(pts).T, ".", color=colour, alpha=0.5, label=f"{CLASS_NAMES[cls]} energy ({len(pts)})")
    other = [(r["x_mm"], r["y_mm"]) for r in reports if not r["valid"] and r["x_mm"] is not None]
    if other:
        ax.plot(*np.array(other).T, "x", color="0.5", label=f"not valid ({len(other)})")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=3, fontsize=8)
    ax.set_title("impacts on the plate")
    return _svg(fig)


def heatmap_figure(reports: list[dict], rig, bin_mm: float = 10.0) -> str:
    import matplotlib.pyplot as plt

    xy = np.array([(r["x_mm"], r["y_mm"]) for r in reports if r["valid"] and r["x_mm"] is not None]).reshape(-1, 2)
    fig, ax = plt.subplots(figsize=(5.5, 5.2))
    bx = np.arange(0, rig.plate_x_mm + bin_mm, bin_mm)
    by = np.arange(0, rig.plate_y_mm + bin_mm, bin_mm)
    h, _, _ = np.histogram2d(xy[:, 0], xy[:, 1], bins=(bx, by))
    im = ax.pcolormesh(bx, by, h.T, cmap="magma_r", shading="flat")
    fig.colorbar(im, ax=ax, label=f"impacts per {bin_mm:g} mm cell", shrink=0.8)
    _plate(ax, rig)
    ax.set_title(f"heat map of {len(xy)} impacts")
    return _svg(fig)


def _times(reports):
    import datetime as dt

    return [dt.datetime.fromtimestamp(r["host_time"]) for r in reports]


def energy_figure(reports: list[dict]) -> str:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 2.8))
    t = np.array([r["host_time"] for r in reports])
    cls = np.array([r["energy_class"] if r["energy_class"] is not None else -1 for r in reports])
    edges = np.linspace(t.min(), t.max() + 1e-6, min(60, max(2, len(t) // 5)) + 1)
    import datetime as dt

    centres = [dt.datetime.fromtimestamp(v) for v in 0.5 * (edges[1:] + edges[:-1])]
    width = (edges[1] - edges[0]) / 86400.0
    bottom = np.zeros(len(edges) - 1)
    for c, colour in CLASS_COLOURS.items():
        n, _ = np.histogram(t[cls == c], bins=edges)
        ax.bar(centres, n, width=width, bottom=bottom, color=colour, label=f"{CLASS_NAMES[c]} energy")
        bottom += n
    ax.set_ylabel("impacts per bin")
    ax.legend(fontsize=8)
    ax.set_title("energy classes over time")
    fig.autofmt_xdate()
    return _svg(fig)


def link_figure(reports: list[dict], connections: list[dict]) -> str:
    """Missing reports (seq gaps) accumulated over time per board, and each connection's CRC errors."""
    import datetime as dt

    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 2.8))
    boards = sorted({r["board_id"] for r in reports})
    for b in boards:
        rs = [r for r in reports if r["board_id"] == b]
        missing, last, out = 0, {}, []
        for r in rs:
            prev = last.get(r["boot"])
            if prev is not None and r["seq"] > prev + 1:
                missing += r["seq"] - prev - 1
            last[r["boot"]] = max(r["seq"], prev if prev is not None else r["seq"])
            out.append(missing)
        ax.step(_times(rs), out, where="post", label=f"{b}: missing reports")
    crc = [(dt.datetime.fromtimestamp(c["closed"]), c["counters"].get("crc_errors", 0)) for c in connections
           if c["closed"] is not None]
    if crc:
        ax.plot(*zip(*crc), "v", color="tab:orange", label="CRC errors per connection (at its end)")
    from matplotlib.ticker import MaxNLocator

    ax.set_ylim(bottom=0, top=max(1.0, ax.get_ylim()[1]))
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_ylabel("count")
    ax.legend(fontsize=8)
    ax.set_title("link health")
    fig.autofmt_xdate()
    return _svg(fig)


def _table(rows: list[dict], keys: list[str]) -> str:
    head = "".join(f"<th>{html.escape(k)}</th>" for k in keys)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(_fmt(r.get(k)))}</td>" for k in keys) + "</tr>" for r in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.1f}"
    return "" if v is None else str(v)


def page(reports: list[dict], summary: list[dict], connections: list[dict], rig, source: str) -> str:
    """The HTML text."""
    import matplotlib

    matplotlib.use("Agg")
    when = lambda t: time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(t))  # noqa: E731
    for s in summary:
        s["first"], s["last"] = when(s["first_host_time"]), when(s["last_host_time"])
    from .eventlog import reason_counts, report_reason

    latest = [dict(r, time=when(r["host_time"]), reason="" if r["valid"] or r["valid"] is None else report_reason(r))
              for r in reports[-50:][::-1]]
    rejected = [{"board_id": b, "boot": boot, "reason": k, "reports": n}
                for (b, boot), counts in reason_counts(reports).items() for k, n in counts.items()]
    parts = [f"<h1>impactsense event log</h1><p>{html.escape(source)}: {len(reports)} reports, "
             f"{len({r['board_id'] for r in reports})} board(s); written {when(time.time())}</p>",
             "<h2>boards and boots</h2>",
             _table(summary, ["board_id", "boot", "reports", "first_seq", "last_seq", "missing", "gaps",
                              "duplicates_ignored", "first", "last"])]
    if reports:
        parts += ["<div class=row>", plate_figure(reports, rig), heatmap_figure(reports, rig), "</div>",
                  energy_figure(reports), link_figure(reports, connections)]
    if rejected:
        parts += ["<h2>reports not valid, per reason</h2>", _table(rejected, ["board_id", "boot", "reason", "reports"])]
    parts += ["<h2>latest reports</h2>",
              _table(latest, ["time", "board_id", "boot", "seq", "x_mm", "y_mm", "uncertainty_mm", "energy_class",
                              "accepted", "valid", "reason"])]
    style = ("body{font-family:sans-serif;margin:2em}table{border-collapse:collapse;font-size:12px}"
             "td,th{border:1px solid #ccc;padding:2px 6px;text-align:right}.row{display:flex;flex-wrap:wrap}"
             "svg{max-width:100%;height:auto}")
    return (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>impactsense events</title>"
            f"<style>{style}</style></head><body>{''.join(parts)}</body></html>")
