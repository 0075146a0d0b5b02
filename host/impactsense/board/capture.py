"""The board's view of drops: what the firmware app captures at the board rate.

The board samples 4 channels with one SAADC, 4 x 50 kHz, channel c read c x 5 us after channel 0 (the scan
order). board_samples turns recordings made at the rig's rate (channels sampled together) into those
frames; the natively compiled firmware app (firmware/lib/impactapp via `impactsense._link.App`) triggers on
them and cuts its captures (board_captures, board_capture, board_view); signal_for_board is the model card's
configuration as the firmware runs it (impactapp::board_core_config). The emulator (link.emulator) and the
board-rate models (board.models) are built on these.
"""

from __future__ import annotations

from dataclasses import replace
from fractions import Fraction

import numpy as np
from scipy.signal import resample_poly

from .. import _core  # noqa: F401  (registers CoreConfig for _link)
from .. import _link
from ..link.record import CaptureAssembler
from .front_end import anti_aliased
from ..signal import (BASELINE_SHARE_OF_PRETRIGGER, CORE_FIELDS, LOCALISER_FIELDS, SignalConfig, config_dict,
                      core_offset, counts_per_core_count, rig_settings)


def board_samples(adc: np.ndarray, fs_in_hz: float, fs_hz: float, scan_step_us: float = _link.SCAN_STEP_US,
                  adc_max: int = 4095, adc_min: int = 0, anti_alias: tuple[float, int] | None = None) -> np.ndarray:
    """What the board's SAADC would read: int16 [R, n, 4] interleaved frames of each recording.

    The recording is interpolated (band-limited, polyphase) onto the scan grid, 1/scan_step = 200 kHz, and
    channel c of frame k is the grid sample D*k + c, D = 200 kHz / fs: channel c is read c * scan_step after
    channel 0, as the SAADC scan does. anti_alias (corner Hz, poles): the board's analog low-pass before the
    SAADC (rig.json `board_front_end`, data.Rig.board_anti_alias; board.front_end.anti_aliased), applied to the
    recording before the scan grid; without it (None, the board as built so far) nothing above fs/2 is removed:
    it aliases as it would on the board. Counts are clipped to [adc_min, adc_max] (the SAADC's range, after the
    filter; the int16 range keeps simulated drops whole), a 16-bit logger's re-centred first as the core takes
    them (signal.core_offset)."""
    off = core_offset(adc_max)
    adc_min, adc_max = adc_min - off, adc_max - off
    grid_hz = 1e6 / scan_step_us
    up = Fraction(grid_hz / fs_in_hz).limit_denominator(1000)
    d = grid_hz / fs_hz
    if abs(d - round(d)) > 1e-9 or round(d) < 4:
        raise ValueError(f"board rate {fs_hz} Hz must divide the {grid_hz:.0f} Hz scan grid at least 4 times")
    d = int(round(d))
    x = np.asarray(adc, dtype=np.float32) - np.float32(off)
    if anti_alias is not None:
        x = anti_aliased(x, fs_in_hz, *anti_alias)
    r, _, n = x.shape
    n_out = (int(n * up) - 3) // d
    y = np.empty((r, n_out, 4), dtype=np.int16)
    if up == 2:
        # Fast path (the rig's 100 kHz onto a 200 kHz grid): even grid points are the recorded samples,
        # odd ones the half-sample band-limited interpolation (a Kaiser-windowed sinc, 32 taps).
        k = np.arange(-15, 17) - 0.5
        h = (np.sinc(k) * np.kaiser(k.size, 8.0)).astype(np.float32)
        h /= h.sum()
        for c in range(4):
            g0 = d * np.arange(n_out) + c
            if g0[0] % 2 == 0 and d % 2 == 0:
                v = x[:, c, g0 // 2]
            else:
                mean = x[:, c, :].mean(axis=1, keepdims=True)
                xp = np.pad(x[:, c, :] - mean, ((0, 0), (15, 16 + d)), mode="edge")  # xp[i + 15] = x[i]
                i0 = g0 // 2  # x at i0 + 0.5 = sum_j h[j] x[i0 - 15 + j]
                half = np.zeros((x.shape[0], n_out), dtype=np.float32)
                if d % 2 == 0:  # i0 advances by d/2: strided slices, one multiply-add a tap
                    step = d // 2
                    for j in range(h.size):
                        half += h[j] * xp[:, i0[0] + j:i0[0] + j + step * n_out:step]
                else:
                    for j in range(h.size):
                        half += h[j] * xp[:, i0 + j]
                half += mean
                v = half if np.all(g0 % 2) else np.where(g0 % 2 == 0, x[:, c, np.minimum(i0, n - 1)], half)
            y[:, :, c] = np.clip(np.rint(v), adc_min, adc_max)
        return y
    mean = x.mean(axis=2, keepdims=True)
    g = resample_poly(x - mean, up.numerator, up.denominator, axis=2) + mean if up != 1 else x
    for c in range(4):
        y[:, :, c] = np.clip(np.rint(g[:, c, c::d][:, :n_out]), adc_min, adc_max)
    return y


def signal_for_board(rig, signal: dict | None = None, fs_hz: int = 50000):
    """The SignalConfig the firmware runs: the model card's settings (or the defaults for the rig) taken to
    the board's rate and acquisition by the firmware's own function (impactapp::board_core_config: sample
    counts scaled, the board rate, the SAADC scan's capture delays), the rig's ADC rail and geometry."""
    signal = {k: v for k, v in (signal or {}).items() if k != TRIGGER_KEY}   # the trigger is the app's (app_config)
    card = SignalConfig.from_dict(signal) if signal else SignalConfig.for_rig(rig)
    rails = rig_settings(rig)
    board = config_dict(_link.board_core_config(card.core(), int(fs_hz), rails["adc_min"], rails["adc_max"]))
    changed = {f.name: board[f.name] for f in CORE_FIELDS if f.role != "COPY"}
    geometry = {k: v for k, v in rig_settings(rig).items() if k in {f.name for f in LOCALISER_FIELDS}}
    return SignalConfig.from_dict({**card.to_dict(), **changed, **geometry})


# The key of an exported signal dict (forest_tables.npz, board.capture.board_signal) that carries the trigger threshold
# export chose (board counts, impactcore.h's at 12 bits); absent: the firmware's default (impactcore.h TriggerConfig).
TRIGGER_KEY = "trigger_counts"


def trigger_counts(signal: dict | None = None) -> tuple[float, float]:
    """(threshold, rearm) of the board's trigger in board counts: the exported signal's TRIGGER_KEY or the firmware's
    default (impactcore.h TriggerConfig); the re-arm level is the default's unless the threshold is not above it,
    then a third of the threshold (impactapp.cpp's rule for set_threshold and exported_config)."""
    trig = _core.TriggerConfig()
    thr = float((signal or {}).get(TRIGGER_KEY) or trig.threshold_counts)
    rearm = float(trig.rearm_counts)
    return thr, (rearm if rearm < thr else thr / 3.0)


def board_signal(card: dict) -> dict:
    """A board model card's signal dict as the export writes it for the board: with TRIGGER_KEY where the card's
    board_trigger chose a threshold (board_counts; board.trigger.choose_trigger), as it is otherwise."""
    signal = dict(card.get("signal") or {})
    chosen = (card.get("board_trigger") or {}).get("board_counts")
    if chosen is not None:
        signal[TRIGGER_KEY] = float(chosen)
    return signal


def app_config(rig, fs_hz: int = 50000, signal: dict | None = None, **extra) -> dict:
    sig = signal_for_board(rig, signal, fs_hz)
    cfg = {"fs_hz": int(fs_hz), "core": sig.core(), "loc": sig.localiser()}
    scale = counts_per_core_count(rig)
    thr, rearm = trigger_counts(signal)
    if scale != 1.0 or TRIGGER_KEY in (signal or {}):   # the trigger's counts (board counts) at the rig's ADC
        cfg.update(threshold_counts=thr * scale, rearm_counts=rearm * scale)
    cfg.update(extra)
    return cfg


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


def _quiet_line(quiet: np.ndarray):
    """A quiet start's least-squares line per channel: (level at its middle, slope a sample, residual, length)."""
    q = np.asarray(quiet, np.float64)
    m = q.shape[-1]
    t = np.arange(m) - 0.5 * (m - 1)
    level = q.mean(-1, keepdims=True)
    slope = (q * t).sum(-1, keepdims=True) / max(float((t * t).sum()), 1.0)
    return level, slope, q - level - slope * t, m


def continued_back(quiet: np.ndarray, lead: int) -> np.ndarray:
    """`lead` samples before `quiet` (a record's quiet start [..., m]) that run forward in time into it: its
    least-squares line (level and slope per channel: a hum or a drift goes on through the join with its own phase
    and slope, no kink) extended back over as long as the quiet start itself and held beyond (bounded by the
    quiet start's own span), plus its residual about the line mirrored back and forth (its noise, no step).
    Float [..., lead]."""
    level, slope, resid, m = _quiet_line(quiet)
    noise = np.pad(resid, [(0, 0)] * (resid.ndim - 1) + [(lead, 0)], mode="symmetric")[..., :lead]
    t = np.maximum(np.arange(-lead, 0), -m) - 0.5 * (m - 1)
    return level + slope * t + noise


def held_level(quiet: np.ndarray) -> np.ndarray:
    """The level continued_back holds beyond its quiet start's own span: [...]."""
    level, slope, _, m = _quiet_line(quiet)
    return (level + slope * (-m - 0.5 * (m - 1)))[..., 0]


def continued_for_capture(adc: np.ndarray, fs_in_hz: float, capture_frames: int, fs_hz: float,
                          baseline_samples: int = 64, pretrigger_frames: int = 0,
                          pretrigger_samples: int | None = None) -> np.ndarray:
    """Recordings long enough for the board between two drops (its capture window, then the trigger's hold-off,
    about as long again): a record shorter than twice the window (a fast logger's or a short capture: the board
    would cut the drop off, or sleep through the next) is continued to 2.5 windows by each channel's
    pre-trigger baseline (the median of its first samples). Longer records are returned as they are.
    A record whose quiet start (`pretrigger_samples`, the session's) is so short that the board's capture
    (`pretrigger_frames` before its trigger, at fs_hz) would reach back past its baseline segment
    (`baseline_samples` frames) into the previous record is also led in by its quiet start: the board then seeks
    the onset on the record's own level, not on the step to the previous record's (records carry their own
    offsets). Its capture then starts within the lead-in (continued_back: the quiet start's level, slope and
    noise, so a hum runs on through it)."""
    adc = np.asarray(adc)
    n = adc.shape[-1]
    per_frame = float(fs_in_hz) / float(fs_hz)
    window = capture_frames * per_frame
    reach = (pretrigger_frames - baseline_samples + 16) * per_frame
    short = pretrigger_samples is not None and pretrigger_frames > 0 and pretrigger_samples < reach
    lead = int(np.ceil((1.25 * pretrigger_frames + 16) * per_frame)) - int(pretrigger_samples) if short else 0
    if lead == 0 and n >= 2.0 * window:
        return adc
    if lead:   # the quiet start continued back (continued_back: its level, slope and noise), as long as needed
        quiet = adc[..., :max(2, int(BASELINE_SHARE_OF_PRETRIGGER * int(pretrigger_samples)))]
        head = np.rint(continued_back(quiet, lead)).astype(adc.dtype)
        adc = np.concatenate([head, adc], axis=-1)
    if n + lead >= 2.0 * window:
        return adc
    base = np.rint(np.median(adc[..., lead:lead + max(1, min(baseline_samples, n))], axis=-1, keepdims=True))
    tail = np.broadcast_to(base, adc.shape[:-1] + (int(np.ceil(2.5 * window)) - n - lead,)).astype(adc.dtype)
    return np.concatenate([adc, tail], axis=-1)


# A join between two records whose levels differ by JOIN_STEP_SHARE of the trigger's threshold floor or more (a step
# that can fire it) is crossfaded over enough frames that the level moves by at most JOIN_SLOPE_SHARE of the
# threshold a frame (the trigger's baseline, 1/8 a frame, then lags it by a quarter of the threshold at most).
JOIN_STEP_SHARE = 1.0
JOIN_SLOPE_SHARE = 1.0 / 32.0
_LEVEL_SAMPLES = 8
JOIN_QUIET_MARGIN = 16   # samples kept clear of a quiet start's first departure (an arrival's rise)


def _quiet_lengths(x: np.ndarray, start: np.ndarray, quiet_n: int, threshold_counts: float) -> list[int]:
    """Each record's quiet start [R, 4, n] -> its length: quiet_n samples, cut JOIN_QUIET_MARGIN samples before
    the first where a channel leaves its start level (start [R, 4]) by half the trigger's threshold (an arrival
    inside the declared quiet start: continued back it would put the drop into the lead-in)."""
    away = np.abs(x[..., :quiet_n] - start[..., None]) >= 0.5 * threshold_counts
    first = np.where(away.any(-1), away.argmax(-1), quiet_n).min(-1)
    return [int(v) for v in np.clip(first - JOIN_QUIET_MARGIN, min(_LEVEL_SAMPLES, quiet_n), quiet_n)]


def joined_without_steps(adc: np.ndarray, threshold_counts: float, per_frame: float,
                         pretrigger_samples: int | None = None, reach_samples: int = 0) -> np.ndarray:
    """Records [R, 4, n] (in the order the stream takes them) joined as the board's continuous stream sees the
    plate between two drops: no step. Each record carries its own offsets (and a hum's phase), so record k's
    start may sit above record k-1's end by more than the trigger's threshold (threshold_counts, the rig's
    counts): fed as it is the step fires the trigger on the quiet start, and the capture's baseline then lies on
    the previous record's level, its onset at the step (a drop the board never sees). Where some join steps by
    JOIN_STEP_SHARE of the threshold or more, every record is led in by its own quiet start continued back in time
    (continued_back: its level, slope and noise; a hum runs on with its own phase) over reach_samples (the
    board's pre-trigger in the record's samples: as far back as a capture can reach), and before that by a
    raised-cosine crossfade from the previous record's end level to that continuation, long enough for the
    largest step at JOIN_SLOPE_SHARE of the threshold a frame (per_frame: the record's samples a board frame);
    the first record's lead is its own quiet start continued back. A capture so never holds the crossfade.
    Records without such a step anywhere are returned as they are."""
    adc = np.asarray(adc)
    if adc.ndim != 3 or adc.shape[0] < 2 or not threshold_counts > 0:
        return adc
    k = min(_LEVEL_SAMPLES, adc.shape[-1])
    x = adc.astype(np.float64)
    start, end = x[..., :k].mean(-1), x[..., -k:].mean(-1)
    if np.abs(start[1:] - end[:-1]).max() < JOIN_STEP_SHARE * threshold_counts:
        return adc
    quiet_n = max(2, int(BASELINE_SHARE_OF_PRETRIGGER * int(pretrigger_samples))) if pretrigger_samples else k
    quiet = [x[r, :, :n] for r, n in enumerate(_quiet_lengths(x, start, quiet_n, threshold_counts))]
    held = np.stack([held_level(q) for q in quiet])
    step = max(np.abs(held[1:] - end[:-1]).max(), JOIN_STEP_SHARE * threshold_counts)
    fade = int(np.ceil(np.pi / 2 * step / (JOIN_SLOPE_SHARE * threshold_counts) * per_frame))
    lead = fade + max(0, int(reach_samples))
    own = np.stack([continued_back(q, lead) for q in quiet])
    # record k's lead starts on record k-1's end level (not its samples: a plate may still ring there)
    before = np.concatenate([own[:1], np.broadcast_to(end[:-1, :, None], own[1:].shape)])
    w = np.ones(lead)
    w[:fade] = 0.5 - 0.5 * np.cos(np.pi * (np.arange(fade) + 0.5) / fade)   # 0 -> 1: the previous end -> own
    head = np.rint((1.0 - w) * before + w * own).astype(adc.dtype)
    return np.concatenate([head, adc], axis=-1)


def board_frames(adc: np.ndarray, rig, app, fs_hz: int = 50000, adc_min: int = 0,
                 adc_max: int | None = None, threshold_counts: float | None = None) -> np.ndarray:
    """Recorded drops as the board's stream: int16 [R, n, 4] frames, one drop after the other as they come in
    the lab (seconds apart: the plate quiet between them). Each record is continued for the app's capture and
    hold-off and led in by its quiet start when it is short (continued_for_capture), then read as the SAADC
    scans it (board_samples). Records fed back to back as they are would be a stream no board sees: 8 ms
    records with 30 samples before the hit put a drop every 8 ms, inside the app's capture and hold-off (the
    app then rightly takes them for one event) and before it has armed. Every path that replays recordings
    through the app (board_captures, board_capture, the emulator, the qemu test image's fixture) reads this.
    adc_min, adc_max: the rails (board_samples; default the rig's ADC). The rig's declared front-end low-pass
    (board_anti_alias) is applied before the scan grid. threshold_counts: the app's trigger threshold in the rig's
    counts (app_config's; default the firmware's default at the rig's ADC): the joins' steps are judged against it."""
    adc = continued_for_capture(adc, rig.fs_hz, app.capture_frames, fs_hz, app.core_config.baseline_samples,
                                app.pretrigger_frames, rig.pretrigger_samples)
    if threshold_counts is None:
        threshold_counts = _core.TriggerConfig().threshold_counts * counts_per_core_count(rig)
    per_frame = float(rig.fs_hz) / float(fs_hz)
    adc = joined_without_steps(adc, float(threshold_counts), per_frame, rig.pretrigger_samples,
                               int(np.ceil(app.pretrigger_frames * per_frame)))
    return board_samples(adc, rig.fs_hz, fs_hz, adc_max=rig.adc_max if adc_max is None else adc_max,
                         adc_min=adc_min, anti_alias=board_anti_alias(rig, fs_hz))


def board_anti_alias(rig, fs_hz: float) -> tuple[float, int] | None:
    """The board's front-end low-pass the emulated board applies to the rig's recordings (board_samples'
    anti_alias): rig.json's `board_front_end` when the recordings are faster than the board (a lab logger's,
    taken without the board's front end); None otherwise (none declared, or a session the board recorded itself,
    `impactsense record`: its samples came through the filter already)."""
    aa = getattr(rig, "board_anti_alias", None)
    return aa if aa is not None and float(rig.fs_hz) > float(fs_hz) + 1 else None


def front_end_card(rig, fs_hz: float) -> dict:
    """The model card's record of the front end the board's models were trained through (board_anti_alias):
    {"board_front_end": {"anti_alias_hz", "anti_alias_poles"}}, or {} without one."""
    aa = board_anti_alias(rig, fs_hz)
    return {} if aa is None else {"board_front_end": {"anti_alias_hz": aa[0], "anti_alias_poles": aa[1]}}


def replay_reports(app, frames: np.ndarray) -> tuple[list[list[dict]], list[list]]:
    """The app fed each drop's frames in turn: per drop, the reports it sent meanwhile and each one's raw
    capture (None without dump_raw)."""
    dec, asm = _link.Decoder(), CaptureAssembler()
    reports, captures = [], []
    for k in range(frames.shape[0]):
        reps, caps = [], []
        for f in dec.feed(app.feed(frames[k])):
            if f["kind"] == "raw":
                asm.add(f["raw"])
            elif f["kind"] == "report":
                reps.append(f["report"])
                caps.append(asm.take(f["report"]["seq"]))
        reports.append(reps)
        captures.append(caps)
    return reports, captures


def board_captures(session, fs_hz: int = 50000, signal: dict | None = None):
    """(captures int16 [R, 4, n], recording index [R], SignalConfig) taken by the firmware app from the
    session's drops as the board samples them (board_frames), one drop after the other."""
    cfg = app_config(session.rig, fs_hz, signal, dump_raw=True)
    app = _link.App(cfg, None)
    frames = board_frames(session.adc, session.rig, app, fs_hz, threshold_counts=cfg.get("threshold_counts"))
    caps, rows = _captures((i, app.feed(frames[i])) for i in range(frames.shape[0]))
    if not caps:
        raise ValueError(f"{session.path}: the emulated board captured none of the {len(session)} drops")
    return np.stack(caps), np.asarray(rows), signal_for_board(session.rig, signal, fs_hz)


def board_capture(rig, fs_hz: int = 50000, signal: dict | None = None):
    """The board as a capture hook (sitemap.build_site_map's `capture`): counts int16 [R, 4, n] at the rig's
    rate -> (captures int16 [R', 4, m], rows [R']) as the firmware app takes them at fs_hz: board_frames
    (continued, resampled, SAADC scan delays) with the int16 range kept instead of the ADC's, then the app's trigger,
    pre-trigger and window (the emulator's path for recorded drops)."""
    cfg = app_config(rig, fs_hz, signal, dump_raw=True)

    def capture(counts: np.ndarray):
        app = _link.App(cfg, None)
        frames = board_frames(counts, rig, app, fs_hz, adc_min=-32768, adc_max=32767,
                              threshold_counts=cfg.get("threshold_counts"))
        caps, rows = _captures((i, app.feed(frames[i])) for i in range(frames.shape[0]))
        if not caps:
            return np.zeros((0, 4, app.capture_frames), np.int16), np.zeros(0, int)
        return np.stack(caps), np.asarray(rows, int)

    return capture


def board_view(session, fs_hz: int, signal: dict | None = None):
    """`session` as the board captures it: the firmware app's captures (board_captures:
    resampled to 4 x fs_hz with the SAADC scan delays, triggered and cut by the app) as its adc; drops the
    app did not capture are left out. signal: board_captures' (a chosen trigger, TRIGGER_KEY)."""
    caps, rows, _ = board_captures(session, fs_hz, signal)
    return replace(session.subset(rows), adc=caps)


# A capture whose first onset pick lies within LATE_TRIGGER_FRAMES of the core's baseline segment's end was taken
# late: the trigger fired so long after the first arrival that the pre-trigger frames no longer hold the quiet
# before it (the arrival runs into the baseline, its onset read as a glitch or a later cycle).
LATE_TRIGGER_FRAMES = 8


def trigger_record(session, caps, feats, sig, excluded=None, board_counts: float | None = None) -> dict:
    """The board's trigger on the session's drops as the emulated board took them (board_captures): its threshold
    floor in the rig's counts (the app's default, impactcore.h TriggerConfig, at the rig's ADC), the drops it
    captured of those recorded (excluded rows not counted) and how many captures it took late (LATE_TRIGGER_FRAMES).
    board_counts: the threshold export chose (board.trigger.choose_trigger; None: the default), recorded as such."""
    first = np.asarray(feats.raw["toa_threshold"], float)
    first = np.where(np.isfinite(first) & (first >= 0), first, np.inf).min(1)
    n = len(session) - int(np.count_nonzero(excluded)) if excluded is not None else len(session)
    thr = trigger_counts(None if board_counts is None else {TRIGGER_KEY: board_counts})[0]
    return {"threshold_counts": round(float(thr * counts_per_core_count(session.rig)), 2),
            **({} if board_counts is None else {"board_counts": float(board_counts)}),
            "drops": int(n), "captured": int(len(caps)),
            "late": int(np.count_nonzero(np.isfinite(first) & (first < int(sig.baseline_samples) + LATE_TRIGGER_FRAMES)))}
