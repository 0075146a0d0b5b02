"""Models trained on the firmware's own inputs: the captures the firmware app takes from the board-rate
stream (4 x 50 kHz, SAADC scan delays included), through `impactsense train`'s own model code.

The trainer (impactsense.workflow.train) fits on the lab's 100 kHz recordings; the board samples 4 x 50 kHz,
where the onset picks scatter more and energies and sample counts differ, so a 100 kHz model loses most of
its accuracy on the board. Until sessions are recorded on the board (`impactsense record`), this trains the
same model type, with the same split and settings, on what the emulated board captures: the recordings
resampled onto the scan grid, channel c read c x 5 us after channel 0 (link.emulator.board_samples),
triggered and cut by the firmware app itself. `impactsense export` ships such models by default.

A model with the twin's site map (`impactsense train --site-map`: position and energy class from the twin's
match) needs the map as the board sees it too: the twin's simulated drops taken the same way (board_site_map; ~3,500 drops for a 5 mm
grid, a few minutes on 2 cores, cached in the export folder).
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np

from .. import _link
from .emulator import Emulator, app_config, board_samples, signal_for_board
from .record import CaptureAssembler

BOARD_SITE_MAP = "board-site-map.npz"   # the cached board-rate site map in an export folder


def _captures(drops) -> tuple[list, list]:
    """The raw captures a dump-raw app wrote, from (index, serial bytes) per drop: (captures, indices)."""
    dec = _link.Decoder()
    asm = CaptureAssembler()
    caps, rows = [], []
    for i, data in drops:
        for f in dec.feed(data):
            if f["kind"] == "raw":
                asm.add(f["raw"])
            elif f["kind"] == "report":
                cap = asm.take(f["report"]["seq"])
                if cap is not None:
                    caps.append(cap)
                    rows.append(i)
    return caps, rows


def board_captures(session, fs_hz: int = 50000, signal: dict | None = None):
    """(captures int16 [R, 4, n], recording index [R], SignalConfig) taken by the firmware app."""
    emu = Emulator(session, None, fs_hz=fs_hz, signal=signal, dump_raw=True)
    caps, rows = _captures(emu.drops())
    if not caps:
        raise ValueError(f"{session.path}: the emulated board captured none of the {len(session)} drops")
    return np.stack(caps), np.asarray(rows), emu.signal


def board_capture(rig, fs_hz: int = 50000, signal: dict | None = None):
    """The board as a capture hook (sitemap.build_site_map's `capture`): counts int16 [R, 4, n] at the rig's
    rate -> (captures int16 [R', 4, m], rows [R']) as the firmware app takes them at fs_hz: board_samples
    (resampled, SAADC scan delays) with the int16 range kept instead of the ADC's, then the app's trigger,
    pre-trigger and window (the emulator's path for recorded drops)."""
    cfg = app_config(rig, fs_hz, signal, dump_raw=True)

    def capture(counts: np.ndarray):
        frames = board_samples(counts, rig.fs_hz, fs_hz, adc_max=32767, adc_min=-32768)
        app = _link.App(cfg, None)
        caps, rows = _captures((i, app.feed(frames[i])) for i in range(frames.shape[0]))
        if not caps:
            return np.zeros((0, 4, app.capture_frames), np.int16), np.zeros(0, int)
        return np.stack(caps), np.asarray(rows, int)

    return capture


def board_site_map(source, rig, fs_hz: int = 50000, cache=None, workers: int = 2, progress: bool = True,
                   step_mm: float | None = None):
    """The twin's site map as the board sees it (sitemap.SiteMap): the grid and reference height of `source`
    (a site map made at the rig's rate), drops simulated with the twin it was made with
    (source.source["sim_params"]), taken by the board (board_capture) and featurized with the board's signal
    (the source map's settings at fs_hz, scan delays). Read from / written to `cache` (reused when made from
    the same source map at the same rate). step_mm: another grid step than the source's (coarse maps for
    tests)."""
    from ..errors import DataError
    from ..sim.params import SimParams
    from ..sitemap import SiteMap, build_site_map

    step = float(step_mm or source.step_mm)
    key = {"from_site_map_sha": source.fingerprint(), "board_fs_hz": int(fs_hz), "step_mm": step}
    if cache is not None and Path(cache).is_file():
        try:
            cached = SiteMap.load(cache)
        except DataError:
            cached = None
        if cached is not None and all(cached.source.get(k) == v for k, v in key.items()):
            return cached
    raw = source.source.get("sim_params")
    if not raw:
        raise DataError("site map", "source.sim_params", "missing: the board's map needs the twin the map was made with")
    params = SimParams.from_dict(raw, "site map source.sim_params")
    src_signal = source.source.get("signal") or None
    board = build_site_map(params, rig, signal_for_board(rig, src_signal, fs_hz), step_mm=step,
                           margin_mm=source.x0_mm, ref_height_mm=source.ref_height_mm, workers=workers,
                           progress=progress, capture=board_capture(rig, fs_hz, src_signal))
    if step == source.step_mm and (board.nx, board.ny, board.y0_mm) != (source.nx, source.ny, source.y0_mm):
        raise DataError("site map", "grid", "the source map's grid is not one build_site_map makes (x0 != y0?)")
    board.source.update(key, calibration=source.source.get("calibration"))
    if cache is not None:
        board.save(cache)
    return board


def train_board_models(session, out_dir, n_trees: int = 30, seed: int = 0, fs_hz: int = 50000,
                       test_fraction: float = 0.2, max_depth: int | None = None, settings=None,
                       exclude_rows=None, train_rows=None, extra_card: dict | None = None,
                       site_map=None) -> Path:
    """Writes a MODEL_DIR (impactsense.models.ImpactModel) trained on the board's captures of the training
    drops of `session`: the physics localiser (group velocity, the rig's channel delays) fitted on the
    board-rate picks, then the forests on the board-rate features.

    The split is the trainer's (split.case_split with test_fraction, seed, exclude_rows) unless train_rows
    (row indices) is given; the card lists the held-out recording ids (`test_recording_ids`, and `split`
    as `impactsense train` writes it). settings (models.ForestSettings) overrides n_trees/seed/max_depth.
    site_map: a board-rate site map (board_site_map): the energy class then reads the twin's estimate.
    The card's rig_delay_us are the rig's own; its capture_delay_us the scan's (the firmware sets its own)."""
    from ..models import ForestSettings, ImpactModel
    from ..pipeline import featurize, fit_localiser
    from ..split import case_split

    if train_rows is None:
        train_rows, _ = case_split(session.case_id, test_fraction, seed, exclude_rows)
    train_rows = np.asarray(train_rows, int)
    excluded = np.zeros(len(session), bool)
    if exclude_rows is not None and len(exclude_rows):
        excluded[np.asarray(exclude_rows, int)] = True
    caps, rows, sig = board_captures(session, fs_hz)
    is_train = np.isin(rows, train_rows)
    is_test = ~is_train & ~excluded[rows]
    board = SimpleNamespace(adc=caps, xy_mm=session.xy_mm[rows], rig=session.rig)
    board = SimpleNamespace(adc=caps, xy_mm=session.xy_mm[rows], rig=session.rig)
    # the rig's delays (the scan's are the capture's); the board's onset threshold as configured (its picks
    # at 50 kHz are coarser than the rig's: a threshold chosen on them would move the rig's delays)
    sig = fit_localiser(board, np.flatnonzero(is_train), sig, choose_threshold=False)
    feats = featurize(caps, sig)
    settings = settings or ForestSettings(n_estimators=n_trees, seed=seed, max_depth=max_depth)
    model = ImpactModel.fit(feats.take(np.flatnonzero(is_train)), session.xy_mm[rows][is_train],
                            session.height_mm[rows][is_train], session.rig.ball_mass_g, sig, settings,
                            site_map=site_map)
    ids = session.recording_id
    split = {
        "data_path": str(session.path),
        "data_hash": session.fingerprint(),
        "test_fraction": test_fraction,
        "seed": seed,
        "train_recordings": ids[rows[is_train]].tolist(),
        "test_recordings": ids[rows[is_test]].tolist(),
        "excluded_recordings": ids[excluded].tolist(),
        "not_captured_recordings": ids[np.setdiff1d(np.arange(len(session)), rows)].tolist(),
    }
    card = {"board_fs_hz": int(fs_hz), "data": str(session.path), "split": split,
            "test_recording_ids": split["test_recordings"], **(extra_card or {})}
    return Path(model.save(out_dir, extra_card=card))


def retrain_for_board(model_dir, out_dir, fs_hz: int = 50000, site_map_cache=None) -> Path:
    """The model of MODEL_DIR (a 100 kHz `impactsense train` model) trained again on the board's captures of
    the same training drops, with the same forest settings; the held-out drops stay held out. A model with
    the twin's site map gets the board's site map (board_site_map, cached in site_map_cache)."""
    from ..data import MODEL_CARD_MISSING, load_session, read_json
    from ..errors import DataError
    from ..models import ForestSettings

    from ..modelfolder import read_card

    card, card_path = read_card(model_dir)
    if "zero_shot" in card:   # sim-trained: the virtual drops, then the calibration drops' fits, at the board rate
        from ..zeroshot import board_model

        return board_model(model_dir, out_dir, fs_hz, site_map_cache=site_map_cache)
    split = card.get("split")
    if not split or "train_recordings" not in split:
        raise DataError(card_path, "split", "missing key (needed to retrain on the same drops at the board rate)")
    data = split.get("data_path")
    if not data or not Path(data).is_dir():
        raise DataError(card_path, "split.data_path", f"session folder {data!r} not found")
    session = load_session(data)
    if split.get("data_hash") and split["data_hash"] != session.fingerprint():
        raise DataError(card_path, "split.data_hash", f"{data} changed since the model was trained")
    index = {int(r): k for k, r in enumerate(session.recording_id)}
    rows = lambda key: np.asarray([index[int(r)] for r in split.get(key, [])], int)  # noqa: E731
    forest = {k: v for k, v in (card.get("forest") or {}).items() if k in ForestSettings.__dataclass_fields__}
    board_map = None
    if "twin" in card:
        from ..models import SITE_MAP_FILE
        from ..sitemap import SiteMap

        from ..modelfolder import verified_path

        source = SiteMap.load(verified_path(model_dir, card, card_path, card["twin"].get("site_map", SITE_MAP_FILE),
                                            "twin.site_map"))
        board_map = board_site_map(source, session.rig, fs_hz, cache=site_map_cache)
    return train_board_models(session, out_dir, fs_hz=fs_hz, settings=ForestSettings(**forest), site_map=board_map,
                              exclude_rows=rows("excluded_recordings"), train_rows=rows("train_recordings"),
                              test_fraction=float(split.get("test_fraction", 0.2)), seed=int(split.get("seed", 0)),
                              extra_card={"retrained_from": str(Path(model_dir).resolve())})


def board_reports(session, models, signal: dict, fs_hz: int = 50000) -> dict:
    """The firmware app (emulated board, exported node tables) over `session`'s drops: {drop row: the first
    valid report it sent, decoded from the wire}; drops without a valid report are absent."""
    dec, got = _link.Decoder(), {}
    for i, data in Emulator(session, models, fs_hz=fs_hz, signal=signal).drops():
        for f in dec.feed(data):
            if f["kind"] == "report" and f["report"].get("valid", True):
                got.setdefault(i, f["report"])
    return got


def board_accuracy(session, models, signal: dict, energy_threshold_j: float, fs_hz: int = 50000) -> dict:
    """The firmware app (emulated board, exported node tables) over `session`'s drops, scored against the true
    positions and energy classes: Eq. 36 metrics of the reports with valid positions, their class accuracy,
    and how many drops gave a report."""
    from ..metrics import region_metrics
    from ..models import impact_energy_j

    got = board_reports(session, models, signal, fs_hz)
    rows = np.asarray(sorted(got), int)
    pred = np.array([[got[i]["x_mm"], got[i]["y_mm"]] for i in rows]).reshape(-1, 2)
    label = (impact_energy_j(session.height_mm, session.rig.ball_mass_g) >= energy_threshold_j).astype(int)
    cls = np.array([got[i]["energy_class"] for i in rows], int)
    return {"n": len(session), "reported": int(rows.size), "fs_hz": int(fs_hz),
            **region_metrics(session.xy_mm[rows], pred, session.rig.inner_region_mm),
            "energy_class_accuracy": float(np.mean(cls == label[rows])) if rows.size else float("nan")}


def held_out_rows(card: dict):
    """(session, row indices of the model card's held-out drops), rows None when the card lists none. A
    sim-trained model's (zeroshot) are the measured test split, the calibration drops never in it."""
    from ..data import load_session

    split = card.get("zero_shot") or card.get("split") or {}
    ids = split.get("test_recordings")
    if ids is None:
        ids = card.get("test_recording_ids")
    data = split.get("data_path") or card.get("data")
    s = load_session(data if data and Path(str(data)).is_dir() else None)
    want = split.get("recordings_hash"), split.get("data_hash")
    if any(want) and not (want[0] and want[0] == s.recordings_hash()) and not (want[1] and want[1] == s.fingerprint()):
        from ..errors import DataError

        raise DataError("model card", "split.data_path", f"the model's session {data!r} is not there or has other "
                        f"recordings now ({s.path} read instead): its held-out drops cannot be scored")
    if ids is None:
        return s, None
    index = {int(r): k for k, r in enumerate(s.recording_id)}
    return s, np.asarray([index[int(r)] for r in ids if int(r) in index], dtype=int)


def held_out_features(card: dict):
    """(Features, true xy [R, 2], heights [R]) of the card's held-out drops (all drops if it lists none) as
    the model sees them: a board-rate model's through the emulated board's captures."""
    from ..pipeline import featurize
    from ..signal import SignalConfig

    s, rows = held_out_rows(card)
    rows = np.arange(len(s)) if rows is None else rows
    signal = card.get("signal") or {}
    board_fs = card.get("board_fs_hz")
    if board_fs and abs(float(board_fs) - s.rig.fs_hz) > 1:
        caps, got, sig = board_captures(s.subset(rows), int(board_fs), signal)
        rows = rows[got]
        f = featurize(caps, sig)
    else:
        f = featurize(s.adc[rows], SignalConfig.from_dict(signal))
    return f, s.xy_mm[rows], s.height_mm[rows]
