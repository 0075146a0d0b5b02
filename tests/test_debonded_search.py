"""The twin's channel search on the board's captures of debonded drops (impactcore twin_match, the shipped twin)."""

import numpy as np

from impactsense import _core


def _board_match(session, full_search=False):
    from pathlib import Path

    from impactsense.board.capture import board_captures
    from impactsense.export import firmware_models, load_tables
    from impactsense.models import ImpactModel  # noqa: F401  (the package's models register the core's types)
    from impactsense.pipeline import featurize

    models_dir = Path(__file__).resolve().parents[1] / "models"
    _, signal = firmware_models(models_dir)
    caps, rows, sig = board_captures(session, 50000, signal)
    feats = featurize(caps, sig)
    t = load_tables(models_dir / "forest_tables.npz")["twin"]
    nx, ny, x0, y0, step = t["grid"]
    f32 = lambda a: np.ascontiguousarray(np.asarray(a, np.float32))  # noqa: E731
    # the four-channel start: the physics position (the board's forests would start nearby; the search is the same)
    m = _core.twin_match_batch(
        np.ascontiguousarray(feats.status, np.int32), np.ascontiguousarray(feats.flags, np.uint8),
        f32(feats.toa_us), f32(feats.raw["window_energy"]), f32(feats.raw["diff_energy"]), f32(feats.phys_xy_mm),
        f32(feats.phys_xy_mm), sig.localiser(), np.asarray(t["q"], np.uint8).reshape(-1, 16),
        int(nx), int(ny), float(x0), float(y0), float(step), f32(t["base"]), f32(t["scale"]), f32(t["offset"]),
        f32(t["slope"]), f32(t["weight"]), *map(float, t["config"][:4]), float(t["uncertainty"][2]),
        coarse_cutoff_mm=float(t["config"][4]), full_search=full_search)
    return m, rows


def test_every_debonded_board_drop_leaves_its_disc_out_and_the_merged_recheck_reports_as_before():
    """Every other bundled drop with one disc debonded (two draws, two discs), as the board captures it: the
    cued search leaves that disc out on every drop, also where the other three picks place the drop far off (a
    plate corner: the first candidate's three-channel match there misfits beyond the gain, and before this
    change the search tried all four channels and flagged none, ~99k instructions on the board); it is then
    matched from the cue's position (docs/method.md, "The twin's channel check"). Where the full search (every
    channel in order, the separate recheck and recentring) leaves the same disc out, the cued search (the
    recheck and recentring in one pass, match_recheck) reports the same position to 1e-3 mm: the same sums in
    the same order. Clean drops: no channel left out."""
    from impactsense.data import load_session
    from impactsense.faults import FaultSpec, inject_session

    s1 = load_session("bundled")
    s = s1.subset(np.arange(0, len(s1), 2))
    clean, _ = _board_match(s)
    assert np.all(clean["left_out"] == -1)
    for spec in (FaultSpec(debond=2, seed=0), FaultSpec(debond=1, seed=1)):
        bad = inject_session(s, spec)
        cued, _ = _board_match(bad)
        full, _ = _board_match(bad, full_search=True)
        assert np.all(cued["status"] == 0)
        assert np.all(cued["left_out"] == spec.debond), (spec, np.flatnonzero(cued["left_out"] != spec.debond))
        same = full["left_out"] == spec.debond
        assert same.mean() > 0.95
        np.testing.assert_allclose(np.asarray(cued["xy_mm"])[same], np.asarray(full["xy_mm"])[same], atol=1e-3)
