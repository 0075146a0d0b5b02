"""Session folders: `rig.json`, `impacts.csv`, `recordings.npz` — read, validated, written.

A session is the unit every tool reads: measured (from the lab rig or `impactsense record`) or simulated
(`impactsense simulate-dataset`). Every problem raises `DataError` naming the file and the field.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
import os
import zipfile
import zlib
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path

import numpy as np

from .balls import check_ball_properties
from .errors import DataError

RIG_FILE = "rig.json"
IMPACTS_FILE = "impacts.csv"
RECORDINGS_FILE = "recordings.npz"
IMPACT_COLUMNS = ("recording_id", "case_id", "repetition", "x_mm", "y_mm", "height_mm")
CHANNELS = 4

# rig.json keys and their types; all required.
_RIG_NUMBERS = ("plate_x_mm", "plate_y_mm", "thickness_mm", "density_kg_m3", "sensor_diameter_mm",
                "ball_diameter_mm", "ball_mass_g", "fs_hz", "vref")
_RIG_INTS = ("channels", "samples", "adc_bits", "bias_counts")
_RIG_STRINGS = ("plate_material", "plate_support", "ball_material")
# Optional rig.json fields (docs/method.md "rig.json"): inner_region_mm [x0, x1, y0, y1] (default: the
# sensors' bounding box inset by INNER_INSET_MM); material_axes, material_properties (materials.py);
# pretrigger_samples (the logger's samples before the hit; default: measured from the session's recordings,
# signal.quiet_start_samples); density_kg_m3 may be left out for a material the table knows (its typical density);
# board_front_end {"anti_alias_hz": F, "anti_alias_poles": N} (the board's analog low-pass before its ADC, a
# Butterworth; absent: none; board.front_end); ball_properties {"e_pa", "nu"} (the ball's constants: balls.py).
INNER_INSET_MM = 30.0


@dataclass(frozen=True)
class Sensor:
    name: str
    channel: int
    x_mm: float
    y_mm: float


@dataclass(frozen=True)
class Rig:
    """What was declared about the rig (rig.json), validated."""

    plate_material: str
    plate_x_mm: float
    plate_y_mm: float
    thickness_mm: float
    density_kg_m3: float
    plate_support: str
    sensors: tuple[Sensor, ...]
    sensor_diameter_mm: float
    ball_material: str
    ball_diameter_mm: float
    ball_mass_g: float
    channels: int
    fs_hz: float
    samples: int
    adc_bits: int
    vref: float
    bias_counts: int
    raw: dict = field(default_factory=dict, compare=False, repr=False)
    # The recordings' quiet start (samples before the first arrival): rig.json's `pretrigger_samples`, else
    # what load_session measured on the session (None: not known; the core's baseline segment as declared).
    pretrigger_samples: int | None = field(default=None, compare=False, repr=False)
    # The board's analog anti-alias low-pass before its ADC (rig.json `board_front_end`): (corner Hz, poles) of a
    # Butterworth, None when none is declared (board.front_end; the lab logger's recordings are taken without it).
    board_anti_alias: tuple[float, int] | None = field(default=None, compare=False, repr=False)

    @property
    def sensor_x_mm(self) -> np.ndarray:
        return np.array([s.x_mm for s in self.sensors], dtype=np.float32)

    @property
    def sensor_y_mm(self) -> np.ndarray:
        return np.array([s.y_mm for s in self.sensors], dtype=np.float32)

    @property
    def sensor_xy_mm(self) -> np.ndarray:
        return np.stack([self.sensor_x_mm, self.sensor_y_mm], axis=1)

    @property
    def adc_max(self) -> int:
        return (1 << self.adc_bits) - 1

    @property
    def inner_region_mm(self) -> tuple[float, float, float, float]:
        """(x0, x1, y0, y1) of the inner region the metrics report apart: rig.json `inner_region_mm` when
        given, else the sensors' bounding box inset by INNER_INSET_MM (kept at least a point wide)."""
        given = self.raw.get("inner_region_mm")
        if given is not None:
            return tuple(float(v) for v in given)
        xs, ys = self.sensor_x_mm.astype(float), self.sensor_y_mm.astype(float)
        x0, x1 = xs.min() + INNER_INSET_MM, xs.max() - INNER_INSET_MM
        y0, y1 = ys.min() + INNER_INSET_MM, ys.max() - INNER_INSET_MM
        if x0 > x1:
            x0 = x1 = 0.5 * (xs.min() + xs.max())
        if y0 > y1:
            y0 = y1 = 0.5 * (ys.min() + ys.max())
        return (float(x0), float(x1), float(y0), float(y1))

    def to_dict(self) -> dict:
        return dict(self.raw)


@dataclass
class Session:
    """One session folder in memory. Arrays are indexed by recording_id (row order)."""

    path: Path
    rig: Rig
    recording_id: np.ndarray  # int64 [R]
    case_id: np.ndarray       # int64 [R]
    repetition: np.ndarray    # int64 [R]
    x_mm: np.ndarray          # float64 [R]
    y_mm: np.ndarray          # float64 [R]
    height_mm: np.ndarray     # float64 [R]
    adc: np.ndarray           # uint16 [R, 4, samples]

    def __len__(self) -> int:
        return int(self.adc.shape[0])

    @property
    def name(self) -> str:
        return self.path.name

    @property
    def xy_mm(self) -> np.ndarray:
        return np.stack([self.x_mm, self.y_mm], axis=1)

    @property
    def n_cases(self) -> int:
        return int(np.unique(self.case_id).size)

    def fingerprint(self) -> str:
        """SHA-256 of the three files' contents (the data hash of model cards)."""
        h = hashlib.sha256()
        for name in (RIG_FILE, IMPACTS_FILE, RECORDINGS_FILE):
            with open(self.path / name, "rb") as fh:
                for block in iter(lambda: fh.read(1 << 20), b""):
                    h.update(block)
        return h.hexdigest()

    def recordings_hash(self) -> str:
        """SHA-256 of the recordings' content (the ADC counts and their shape), whatever the files' text."""
        h = hashlib.sha256(repr(self.adc.shape).encode())
        h.update(np.ascontiguousarray(self.adc, dtype="<u2").tobytes())
        return h.hexdigest()

    def subset(self, rows: np.ndarray) -> "Session":
        rows = np.asarray(rows)
        return Session(self.path, self.rig, self.recording_id[rows], self.case_id[rows],
                       self.repetition[rows], self.x_mm[rows], self.y_mm[rows],
                       self.height_mm[rows], self.adc[rows])


def bundled_session_path(name: str = "session-1") -> Path:
    """The session folder shipped inside the package (default data)."""
    return Path(str(resources.files("impactsense") / "data" / name))


def resolve_session_path(path: str | os.PathLike | None) -> Path:
    """`None` or `bundled` (or `bundled:session-1`) means the packaged default data."""
    if path is None or str(path) == "bundled":
        return bundled_session_path()
    text = str(path)
    if text.startswith("bundled:"):
        return bundled_session_path(text.split(":", 1)[1])
    return Path(path)


def read_json(path: str | os.PathLike, missing: str = "file not found") -> dict:
    """A JSON file holding an object, or a DataError naming the file: `missing` when it is not there, else
    what is wrong with it."""
    path = Path(path)
    if not path.is_file():
        raise DataError(path, None, missing)
    try:
        raw = json.loads(path.read_text(encoding="utf-8"))
    except RecursionError:
        raise DataError(path, None, "not valid JSON (nested too deeply)") from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise DataError(path, None, f"not valid JSON ({exc})") from None
    if not isinstance(raw, dict):
        raise DataError(path, None, "must hold a JSON object")
    return raw


MODEL_CARD_MISSING = "model card not found (is this a MODEL_DIR from `impactsense train`?)"


def load_rig(path: str | os.PathLike) -> Rig:
    path = Path(path)
    if path.is_dir():
        path = path / RIG_FILE
    return rig_from_dict(read_json(path), path)


def _finite(v) -> bool:
    """A finite number that fits a float (JSON integers can be any size)."""
    try:
        return math.isfinite(float(v))
    except (OverflowError, ValueError, TypeError):
        return False


def rig_from_dict(raw: dict, path: str | os.PathLike = RIG_FILE) -> Rig:
    def need(key):
        if key not in raw:
            raise DataError(path, key, "missing key")
        return raw[key]

    values: dict = {}
    for key in _RIG_NUMBERS:
        v = _table_density(raw, path) if key == "density_kg_m3" and key not in raw else need(key)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not _finite(v) or v <= 0:
            raise DataError(path, key, f"must be a positive finite number, got {v!r}")
        values[key] = float(v)
    for key in _RIG_INTS:
        v = need(key)
        if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
            raise DataError(path, key, f"must be a positive integer, got {v!r}")
        values[key] = int(v)
    for key in _RIG_STRINGS:
        v = need(key)
        if not isinstance(v, str):
            raise DataError(path, key, f"must be a string, got {v!r}")
        values[key] = v
    if values["channels"] != CHANNELS:
        raise DataError(path, "channels", f"must be {CHANNELS}, got {values['channels']} (impactsense supports "
                                          f"layouts of exactly {CHANNELS} sensors)")
    sensors_raw = need("sensors")
    if not isinstance(sensors_raw, list):
        raise DataError(path, "sensors", f"must be a list of {CHANNELS} sensors")
    if len(sensors_raw) != CHANNELS:
        raise DataError(path, "sensors", f"{len(sensors_raw)} sensors: impactsense supports layouts of exactly "
                                         f"{CHANNELS} sensors (one per channel)")
    sensors = []
    for k, s in enumerate(sensors_raw):
        if not isinstance(s, dict):
            raise DataError(path, f"sensors[{k}]", "must be an object")
        for key in ("name", "channel", "x_mm", "y_mm"):
            if key not in s:
                raise DataError(path, f"sensors[{k}].{key}", "missing key")
        if s["channel"] != k:
            raise DataError(path, f"sensors[{k}].channel", f"must be {k} (channel k = sensor k+1)")
        for key in ("x_mm", "y_mm"):
            v = s[key]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not _finite(v):
                raise DataError(path, f"sensors[{k}].{key}", f"must be a finite number, got {v!r}")
        if not (0 <= s["x_mm"] <= values["plate_x_mm"] and 0 <= s["y_mm"] <= values["plate_y_mm"]):
            raise DataError(path, f"sensors[{k}]", "sensor centre lies off the plate")
        sensors.append(Sensor(str(s["name"]), int(s["channel"]), float(s["x_mm"]), float(s["y_mm"])))
    _check_inner_region(raw.get("inner_region_mm"), values, path)
    check_ball_properties(raw, path)
    _check_rig_sanity(path, values, sensors)
    pre = raw.get("pretrigger_samples")
    if pre is not None and (isinstance(pre, bool) or not isinstance(pre, int) or not 0 < pre < values["samples"]):
        raise DataError(path, "pretrigger_samples", f"must be an integer between 1 and samples - 1, got {pre!r}")
    from .signal import CORE_MAX_SAMPLES
    if pre is not None and pre >= CORE_MAX_SAMPLES:
        raise DataError(path, "pretrigger_samples", f"{pre}: the signal core reads the first {CORE_MAX_SAMPLES} "
                        "samples of each record, so the hit must come before them")
    return Rig(sensors=tuple(sensors), raw=dict(raw), pretrigger_samples=pre,
               board_anti_alias=_board_anti_alias(raw.get("board_front_end"), values["fs_hz"], path), **values)


# The board_front_end low-pass's pole counts (a Butterworth of 1 to 8 poles: an RC stage to four op-amp stages).
ANTI_ALIAS_POLES = (1, 8)
ANTI_ALIAS_DEFAULT_POLES = 4


def _board_anti_alias(front, fs_hz: float, path) -> tuple[float, int] | None:
    """rig.json `board_front_end`: (anti_alias_hz, anti_alias_poles) or None (absent or no anti_alias_hz).
    The corner must lie below the recordings' Nyquist frequency (above it the recordings cannot show what the
    filter does)."""
    if front is None:
        return None
    if not isinstance(front, dict):
        raise DataError(path, "board_front_end", 'must be an object {"anti_alias_hz": F, "anti_alias_poles": N}, '
                                                 f"got {front!r}")
    unknown = sorted(set(front) - {"anti_alias_hz", "anti_alias_poles"})
    if unknown:
        raise DataError(path, f"board_front_end.{unknown[0]}", "unknown key (anti_alias_hz, anti_alias_poles)")
    hz = front.get("anti_alias_hz")
    if hz is None:
        if "anti_alias_poles" in front:
            raise DataError(path, "board_front_end.anti_alias_hz", "missing key (anti_alias_poles is given)")
        return None
    if isinstance(hz, bool) or not isinstance(hz, (int, float)) or not _finite(hz) or not 0 < hz < fs_hz / 2:
        raise DataError(path, "board_front_end.anti_alias_hz", f"must be a corner frequency in Hz between 0 and "
                                                               f"fs_hz / 2 = {fs_hz / 2:g}, got {hz!r}")
    poles = front.get("anti_alias_poles", ANTI_ALIAS_DEFAULT_POLES)
    lo, hi = ANTI_ALIAS_POLES
    if isinstance(poles, bool) or not isinstance(poles, int) or not lo <= poles <= hi:
        raise DataError(path, "board_front_end.anti_alias_poles", f"must be an integer {lo}..{hi}, got {poles!r}")
    return float(hz), int(poles)


def _table_density(raw: dict, path) -> float:
    """A rig.json without `density_kg_m3`: the materials table's typical density of `plate_material`
    (materials.lookup); an error naming the field when the table does not know the material."""
    from .materials import lookup

    words = raw.get("plate_material")
    mat = lookup(words) if isinstance(words, str) else None
    if mat is None or not mat.known:
        raise DataError(path, "density_kg_m3", f"missing key (plate_material {words!r} is not in the materials "
                                               "table, so its density cannot be assumed: declare it)")
    return mat.density_kg_m3.value


def _check_inner_region(region, values: dict, path) -> None:
    if region is None:
        return
    if (not isinstance(region, list) or len(region) != 4
            or any(isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) for v in region)):
        raise DataError(path, "inner_region_mm", f"must be [x0, x1, y0, y1] in mm, got {region!r}")
    x0, x1, y0, y1 = region
    if not (0 <= x0 <= x1 <= values["plate_x_mm"] and 0 <= y0 <= y1 <= values["plate_y_mm"]):
        raise DataError(path, "inner_region_mm", "must lie on the plate with x0 <= x1 and y0 <= y1")


# A data logger's plausible sample rates per channel (Hz): below, no wave front is resolved; above, no ADC.
FS_HZ_RANGE = (1e3, 1e8)


def _check_rig_sanity(path, values: dict, sensors: list) -> None:
    """Facts no real rig has: overlapping sensor discs, an implausible sample rate, a bias outside the ADC."""
    lo, hi = FS_HZ_RANGE
    if not lo <= values["fs_hz"] <= hi:
        raise DataError(path, "fs_hz", f"{values['fs_hz']:g} Hz is not a plausible sample rate ({lo:g}..{hi:g})")
    if values["adc_bits"] > 16:
        raise DataError(path, "adc_bits", f"must be at most 16 (uint16 recordings), got {values['adc_bits']}")
    if values["bias_counts"] >= (1 << values["adc_bits"]):
        raise DataError(path, "bias_counts", f"{values['bias_counts']} lies outside the {values['adc_bits']}-bit "
                                             f"ADC range 0..{(1 << values['adc_bits']) - 1}")
    xy = np.array([[s.x_mm, s.y_mm] for s in sensors], float)
    across = np.linalg.svd(xy - xy.mean(axis=0), compute_uv=False)[-1] / np.sqrt(len(sensors))
    if across < values["sensor_diameter_mm"]:
        raise DataError(path, "sensors", f"the {len(sensors)} sensors lie on one line (rms {across:.1f} mm off it): "
                                         "an impact and its mirror image across that line reach them alike")
    for i in range(len(sensors)):
        for j in range(i):
            d = float(np.hypot(sensors[i].x_mm - sensors[j].x_mm, sensors[i].y_mm - sensors[j].y_mm))
            if d < values["sensor_diameter_mm"]:
                raise DataError(path, f"sensors[{i}]", f"{d:.1f} mm from sensors[{j}]: closer than the discs' "
                                f"diameter ({values['sensor_diameter_mm']:g} mm), two discs cannot be there")


def _read_impacts(path: Path) -> dict[str, np.ndarray]:
    if not path.is_file():
        raise DataError(path, None, "file not found")
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            reader = csv.DictReader(fh)
            header = reader.fieldnames or []
            for col in IMPACT_COLUMNS:
                if col not in header:
                    raise DataError(path, col, "missing column")
            rows = list(reader)
    except UnicodeDecodeError as exc:
        raise DataError(path, None, f"not UTF-8 text (byte {exc.start}: {exc.reason})") from None
    except (csv.Error, OSError) as exc:
        raise DataError(path, None, f"not a readable CSV file ({exc})") from None
    if not rows:
        raise DataError(path, None, "no impacts")
    out: dict[str, np.ndarray] = {}
    for col in IMPACT_COLUMNS:
        is_int = col in ("recording_id", "case_id", "repetition")
        vals = []
        for line, row in enumerate(rows, start=2):
            text = (row.get(col) or "").strip()
            if not text and not is_int:    # unknown (a recorded drop whose truth was not given)
                vals.append(np.nan)
                continue
            try:
                v = int(text) if is_int else float(text)
            except ValueError:
                raise DataError(path, col, f"line {line}: {text!r} is not a number") from None
            if is_int and abs(v) >= 2 ** 31:
                raise DataError(path, col, f"line {line}: {text[:20]!r} is out of range (|id| < 2^31)")
            if not is_int and not np.isfinite(v):
                raise DataError(path, col, f"line {line}: value is {text} (not finite)")
            vals.append(v)
        out[col] = np.asarray(vals, dtype=np.int64 if is_int else np.float64)
    rid = out["recording_id"]
    if not np.array_equal(rid, np.arange(rid.size)):
        bad = int(np.flatnonzero(rid != np.arange(rid.size))[0])
        raise DataError(path, "recording_id",
                        f"ids must be 0..N-1 in order; line {bad + 2} has {rid[bad]}, expected {bad}")
    if np.any(out["repetition"] < 0) or np.any(out["case_id"] < 0):
        raise DataError(path, "case_id/repetition", "must be non-negative")
    if np.any(out["height_mm"] <= 0):  # NaN (unknown) passes
        raise DataError(path, "height_mm", "must be positive")
    return out


def _read_adc(path: Path, rig: Rig, n_rows: int) -> np.ndarray:
    if not path.is_file():
        raise DataError(path, None, "file not found")
    try:
        with np.load(path, allow_pickle=False) as npz:
            if "adc" not in npz.files:
                raise DataError(path, "adc", f"missing array (found {npz.files})")
            adc = npz["adc"]
    except DataError:
        raise
    except (zipfile.BadZipFile, zlib.error, OSError, ValueError, EOFError, KeyError, NotImplementedError,
            RuntimeError, MemoryError) as exc:
        raise DataError(path, "adc", f"unreadable or truncated ({exc})") from exc
    if adc.dtype != np.uint16:
        raise DataError(path, "adc", f"dtype must be uint16 (raw ADC counts), got {adc.dtype}")
    if adc.ndim != 3:
        raise DataError(path, "adc", f"shape must be [recording, channel, sample], got {adc.shape}")
    if adc.shape[1] != CHANNELS:
        raise DataError(path, "adc", f"must have {CHANNELS} channels, got {adc.shape[1]}")
    if adc.shape[0] != n_rows:
        raise DataError(path, "adc", f"{adc.shape[0]} recordings but impacts.csv lists {n_rows}")
    if adc.shape[2] != rig.samples:
        raise DataError(path, "adc", f"{adc.shape[2]} samples per channel but rig.json says {rig.samples}")
    if adc.shape[2] < 256:
        raise DataError(path, "adc", f"{adc.shape[2]} samples per channel is too short a capture")
    if int(adc.max(initial=0)) > rig.adc_max:
        raise DataError(path, "adc", f"counts above the {rig.adc_bits}-bit ADC range")
    return adc


def load_session(path: str | os.PathLike | None = None) -> Session:
    """Reads and validates a session folder (None: the bundled session-1)."""
    path = resolve_session_path(path)
    if not path.is_dir():
        raise DataError(path, None, "session folder not found")
    rig = load_rig(path / RIG_FILE)
    imp = _read_impacts(path / IMPACTS_FILE)
    for col, hi in (("x_mm", rig.plate_x_mm), ("y_mm", rig.plate_y_mm)):
        v = imp[col]
        if np.any((v < 0) | (v > hi)):
            bad = int(np.flatnonzero((v < 0) | (v > hi))[0])
            raise DataError(path / IMPACTS_FILE, col, f"line {bad + 2}: {v[bad]} lies off the plate")
    adc = _read_adc(path / RECORDINGS_FILE, rig, imp["recording_id"].size)
    if rig.pretrigger_samples is None:
        from .signal import quiet_start_samples

        rig = replace(rig, pretrigger_samples=quiet_start_samples(adc, rig))
    return Session(path=path, rig=rig, adc=adc, **imp)


def write_session(path: str | os.PathLike, rig: dict | Rig, x_mm, y_mm, height_mm, adc,
                  case_id=None, repetition=None, force: bool = False, extra_files: dict | None = None) -> Path:
    """Writes a session folder through the package's output writer (outputs.output_folder: staged, swapped in
    whole; a folder with a user's files is refused unless force, and no user's file is ever deleted)."""
    from .outputs import output_folder

    path = Path(path)
    raw = rig.to_dict() if isinstance(rig, Rig) else dict(rig)
    rig_from_dict(raw)  # validate before writing anything
    adc = np.asarray(adc)
    if adc.dtype != np.uint16 or adc.ndim != 3 or adc.shape[1] != CHANNELS:
        raise DataError(path / RECORDINGS_FILE, "adc", "must be uint16 [recording, 4, sample]")
    n = adc.shape[0]
    case_id = np.arange(n) if case_id is None else np.asarray(case_id)
    repetition = np.zeros(n, dtype=int) if repetition is None else np.asarray(repetition)
    cols = [np.asarray(x_mm, float), np.asarray(y_mm, float), np.asarray(height_mm, float)]
    if any(c.shape != (n,) for c in [*cols, case_id, repetition]):
        raise DataError(path / IMPACTS_FILE, None, f"every column needs {n} values")
    raw["samples"] = int(adc.shape[2])
    with output_folder(path, force, tool="impactsense session") as tmp:
        write_session_files(tmp, raw, cols, case_id, repetition, adc)
        for name, text in (extra_files or {}).items():
            (tmp / name).write_text(text)
    return path


def write_session_files(folder: Path, raw: dict, cols, case_id, repetition, adc) -> None:
    """rig.json, impacts.csv (x, y, height: NaN written empty, i.e. unknown) and recordings.npz into folder."""
    (folder / RIG_FILE).write_text(json.dumps(raw, indent=1))
    with open(folder / IMPACTS_FILE, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(IMPACT_COLUMNS)
        for i in range(len(adc)):
            w.writerow([i, int(case_id[i]), int(repetition[i]), *(_num(cols[k][i], f) for k, f in
                                                                   ((0, ".3f"), (1, ".3f"), (2, "g")))])
    np.savez_compressed(folder / RECORDINGS_FILE, adc=adc)


def _num(v: float, fmt: str) -> str:
    return format(v, fmt) if np.isfinite(v) else ""
