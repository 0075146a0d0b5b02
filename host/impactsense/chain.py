"""The step-by-step zero-shot chain: a virtual session that remembers the calibration it was made from.

    impactsense calibrate DATA --out CAL.json
    impactsense simulate-dataset --calibration CAL.json --n 490 --out V
    impactsense train V --out M --test-fraction 0          # --site-map auto
    impactsense evaluate DATA --model M --json OUT.json

`simulate-dataset --calibration` writes CAL.json into V (`calibration.json`, with the file's path and hash).
`train` on such a session does what `demo --zero-shot` does (zeroshot.run_zero_shot): the forests and the
localiser from the virtual drops, the twin's site map (`--site-map auto`: the calibrated twin's, built once
and cached in V, by simulate-dataset beside the virtual drops unless --no-site-map), and then everything the four calibration drops teach the model about the rig
(zeroshot.fit_on_calibration_drops: channel delays and gains, the rig's group velocity at the picks, the
twin's fingerprint offsets and weights, the uncertainty's scale), read from the measured session CAL.json
names. The model card records that session and its drops other than the calibration drops, so `evaluate`
on it scores those drops only (the chain's figure), and `export` can make the model again for the board.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from .data import Session, load_session
from .errors import DataError
from .outputs import write_file

CALIBRATION_FILE = "calibration.json"


def calibration_record(cal_path: str | Path) -> str:
    """CAL.json's text for a virtual session folder, with where it came from (path and SHA-256)."""
    from .zeroshot import read_calibration

    cal_path = Path(cal_path).resolve()
    cal = read_calibration(cal_path)
    cal["source"] = {"path": str(cal_path), "sha256": hashlib.sha256(cal_path.read_bytes()).hexdigest()}
    return json.dumps(cal, indent=1)


def record_calibration(session_dir: str | Path, cal_path: str | Path) -> Path:
    """Writes CAL.json into the virtual session folder (calibration_record), through outputs.write_file."""
    return write_file(Path(session_dir) / CALIBRATION_FILE, calibration_record(cal_path))


def session_calibration(session: Session) -> Path | None:
    """The calibration a virtual session was made from (its copy in the folder), or None."""
    path = Path(session.path) / CALIBRATION_FILE
    return path if path.is_file() else None


def measured_session(cal_path: Path) -> tuple[Session, dict]:
    """The measured session CAL.json was fitted on (its `data`), checked against its hash."""
    from .zeroshot import read_calibration

    cal = read_calibration(cal_path)
    if "data" not in cal:
        raise DataError(cal_path, "data", "missing key (the calibration's measured session)")
    session = load_session(cal["data"])
    want = cal.get("data_sha256")
    if want and want != session.fingerprint():
        raise DataError(cal_path, "data_sha256", f"the session {cal['data']} changed since it was calibrated")
    return session, cal


def site_map(virtual: Session, cal_path: Path, progress: bool = True):
    """The calibrated twin's site map (the bundled twin's when CAL.json is that twin), cached in the folder."""
    from .sim import SimParams
    from .zeroshot import twin_site_map

    session, _ = measured_session(cal_path)
    return twin_site_map(SimParams.from_json(cal_path), session, Path(virtual.path), progress)


def rig_calibration_drops(cal_path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The rig's calibration drops of CAL.json: their recordings (adc) and positions (mm), what `train` on a
    virtual set gives the onset threshold's choice (travel.choose_threshold's rig_drops)."""
    from .calibration_drops import calibration_rows

    session, cal = measured_session(cal_path)
    rows = calibration_rows(session, cal)
    return session.adc[rows], session.xy_mm[rows]


def start_calibration_twins(cal_path: Path, seed: int, workers: int = 1):
    """The calibration drops' simulated twins (what `adapt` needs from the FEM), started in a thread: they
    depend on CAL.json alone, so `train` runs them on the second core while it loads and featurizes the
    virtual drops. Returns a callable that waits for them (uint16 [R, 4, n])."""
    from .sim import SimParams
    from .sim.executor import in_background
    from .zeroshot import calibration_rows, calibration_twins

    session, cal = measured_session(cal_path)
    params, rows = SimParams.from_json(cal_path), calibration_rows(session, cal)
    return in_background(lambda: calibration_twins(params, session, rows, seed, workers), "calibration-twins")


def adapt(model, virtual: Session, cal_path: Path, seed: int, workers: int = 2, cal_sim=None) -> dict:
    """Fits what the calibration drops teach the virtual-trained `model` (in place, as demo --zero-shot);
    returns the model card's record (the fits, the zero-shot record with the measured session's drops that
    are not calibration drops as its test drops). cal_sim: the calibration drops' twins when made already
    (`start_calibration_twins`)."""
    from .sim import SimParams
    from .zeroshot import calibration_rows, calibration_twins, fit_on_calibration_drops, zero_shot_card

    session, cal = measured_session(cal_path)
    params = SimParams.from_json(cal_path)
    rows = calibration_rows(session, cal)
    if cal_sim is None:
        cal_sim = calibration_twins(params, session, rows, seed, workers)
    fits = fit_on_calibration_drops(model, session, rows, cal_sim, model.site_map, virtual)
    fits.pop("_virtual_twin", None)
    test_rows = np.setdiff1d(np.arange(len(session)), rows)
    return {"trained_on": str(virtual.path), **fits,
            **zero_shot_card(cal_path, session, rows, test_rows, seed, len(virtual))}


def measured_site_map(session: Session, cal_path: str | Path, progress: bool = True):
    """The site map of the twin CAL.json calibrated, for training on a measured session of the same rig
    (`train DATA --calibration CAL.json`): built once and cached beside CAL.json (CAL.site-map.npz; rebuilt
    when the twin changed). The session need not be the one CAL.json was fitted on, but its sensors must sit
    where that session's did."""
    from .sim import SimParams
    from .sitemap import rig_matches
    from .zeroshot import read_calibration, twin_site_map

    cal_path = Path(cal_path)
    cal = read_calibration(cal_path)
    rig_session = session
    if cal.get("data_sha256") != session.fingerprint():
        rig_session, _ = measured_session(cal_path)
        if not rig_matches({"rig_sensors_mm": rig_session.rig.sensor_xy_mm.tolist()}, session.rig):
            raise DataError(cal_path, "data", f"calibrated on {rig_session.path}, whose sensors are not where "
                            f"{session.path}'s are (calibrate this rig)")
    return twin_site_map(SimParams.from_json(cal_path), rig_session, cal_path.parent, progress,
                         name=f"{cal_path.stem}.site-map.npz")
