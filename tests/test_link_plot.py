"""`impactsense monitor --plot`: reports read through the transport double are drawn (Agg canvas) where they
say the impact was, coloured by energy class, with the latest report's uncertainty; the JSON lines are the
same with and without the plot; without a display the monitor says so and carries on."""

import io
import json

import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import to_rgba
from matplotlib.figure import Figure

from impactsense import _link
from impactsense.data import load_session
from impactsense.link import monitor as mon
from impactsense.link import plot as lplot
from impactsense.link.protocol import reason_code
from test_link_e2e import FakeTransport


def reports(n):
    rng = np.random.default_rng(1)
    return [dict(seq=i, x_mm=float(rng.uniform(20, 300)), y_mm=float(rng.uniform(20, 300)),
                 uncertainty_mm=float(rng.uniform(0.5, 9)), energy_class=int(i % 3 == 0), accepted=True,
                 order=[0, 1, 2, 3]) for i in range(n)]


def agg_plot(last_n):
    rig = load_session().rig
    fig = Figure()
    FigureCanvasAgg(fig)
    return lplot.LivePlot(fig, (rig.plate_x_mm, rig.plate_y_mm), list(zip(rig.sensor_x_mm, rig.sensor_y_mm)),
                          last_n), rig


def test_plot_shows_the_reported_impacts():
    sent = reports(13)
    stream = b"".join(_link.encode_report(r) for r in sent)
    plot, rig = agg_plot(last_n=8)
    buf = io.StringIO()
    totals = mon.run(lambda: FakeTransport(stream), json_lines=True, out=buf, err=io.StringIO(), plot=plot)
    assert totals["reports"] == 13
    got = [json.loads(s) for s in buf.getvalue().splitlines()]
    shown = got[-8:]  # the last N, as decoded (positions travel in 0.1 mm)
    np.testing.assert_allclose(plot.points.get_offsets(), [[r["x_mm"], r["y_mm"]] for r in shown], atol=0.051)
    np.testing.assert_allclose([r["x_mm"] for r in shown], [r["x_mm"] for r in sent[-8:]], atol=0.051)
    want = [to_rgba(lplot.CLASS_COLOURS[r["energy_class"]]) for r in shown]
    np.testing.assert_allclose(plot.points.get_facecolors(), want)
    last = got[-1]
    assert plot.uncertainty.get_visible()
    np.testing.assert_allclose(plot.uncertainty.center, (last["x_mm"], last["y_mm"]))
    assert plot.uncertainty.get_radius() == pytest.approx(last["uncertainty_mm"], abs=0.051)
    np.testing.assert_allclose(plot.sensors.get_offsets(), np.c_[rig.sensor_x_mm, rig.sensor_y_mm])
    outline = plot.ax.patches[0]
    assert (outline.get_width(), outline.get_height()) == (rig.plate_x_mm, rig.plate_y_mm) == (320.0, 317.0)


def test_plot_leaves_the_json_lines_unchanged_and_skips_invalid_positions():
    sent = reports(5)
    sent[2].update(valid=False, reason=reason_code("channels_missing"))  # no position: a report line, not a point
    stream = b"".join(_link.encode_report(r) for r in sent)
    plain, with_plot = io.StringIO(), io.StringIO()
    mon.run(lambda: FakeTransport(stream), json_lines=True, out=plain, err=io.StringIO())
    plot, _ = agg_plot(last_n=20)
    mon.run(lambda: FakeTransport(stream), json_lines=True, out=with_plot, err=io.StringIO(), plot=plot)
    assert plain.getvalue() == with_plot.getvalue() and len(plain.getvalue().splitlines()) == 5
    assert len(plot.points.get_offsets()) == 4


def test_reader_thread_keeps_the_consumer_ticking():
    """A quiet port: the consumer's tick (the plot redraw) runs while the reader waits for bytes."""
    import threading

    gate = threading.Event()
    ticks = []

    def frames():
        gate.wait(5)
        yield "a"

    def tick():
        ticks.append(1)
        if len(ticks) == 3:
            gate.set()

    assert list(mon.read_in_thread(frames(), tick, tick_s=0.01)) == ["a"]
    assert len(ticks) >= 3


def test_plot_without_a_display_degrades_with_a_message(monkeypatch):
    monkeypatch.setattr(lplot.sys, "platform", "linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    err = io.StringIO()
    assert lplot.open_live_plot((320, 317), [(30, 33)] * 4, err=err) is None
    assert "no display" in err.getvalue() and "continuing without the plot" in err.getvalue()
