"""Model folders that cannot run code: the trust boundary of a model someone else gives you.

A model folder is `model_card.json` plus the files its `files` entry names (role -> file name: the forests,
`.npz` node arrays read with allow_pickle=False, see forestfile.py) and the twin's site map (`.npz`, no
pickles either). Loading:

- reads only the files the card names, each a plain name inside the folder (no path separators, no `..`,
  no symlink out of the folder);
- checks each file's sha256 against the card's `sha256` entry before reading it, so a damaged or swapped
  file is refused with an error naming it;
- refuses pickle-based (`.joblib`, `.pkl`) model files outright: loading a pickle can run any code.

What this does not protect against: a card and files crafted together by someone you do not trust still
load (the checksums only say the folder is whole), and they compute whatever numbers they were made to. It
guarantees that such a folder cannot run code on your machine or crash the loader.
"""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

from .data import MODEL_CARD_MISSING, read_json
from .errors import DataError
from .forestfile import load_forest

CARD_FILE = "model_card.json"
_SAFE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,127}$")
_PICKLE_SUFFIXES = (".joblib", ".pkl", ".pickle", ".sav")


def file_hashes(folder: Path, names) -> dict:
    """sha256 of each named file in folder (for the card's `sha256` entry)."""
    return {n: hashlib.sha256((Path(folder) / n).read_bytes()).hexdigest() for n in sorted(set(names))}


def read_card(model_dir) -> tuple[dict, Path]:
    d = Path(model_dir)
    if not d.is_dir():
        raise DataError(d, None, "model folder not found")
    card_path = d / CARD_FILE
    card = read_json(card_path, MODEL_CARD_MISSING)
    files = card.get("files")
    if not isinstance(files, dict) or not files or not all(isinstance(v, str) for v in files.values()):
        raise DataError(card_path, "files", "must map each model role to a file name in the folder")
    sums = card.get("sha256")
    if not isinstance(sums, dict) or not all(isinstance(v, str) for v in sums.values()):
        raise DataError(card_path, "sha256", "missing: a model folder lists the sha256 of every file (a model "
                                             "from an older impactsense: train it again)")
    return card, card_path


def confined(model_dir, name, card_path, field: str) -> Path:
    """The path of a file the card names, refused unless it is a plain file name inside the folder."""
    d = Path(model_dir)
    if not isinstance(name, str) or not _SAFE_NAME.match(name) or ".." in name:
        raise DataError(card_path, field, f"{name!r} is not a plain file name inside the model folder")
    if name.lower().endswith(_PICKLE_SUFFIXES):
        raise DataError(card_path, field, f"{name}: a pickle-based model file (it could run code when loaded) "
                                          "is never loaded; train the model again with this version")
    path = d / name
    if path.is_symlink() and path.resolve().parent != d.resolve():
        raise DataError(card_path, field, f"{name} links outside the model folder")
    if not path.is_file():
        raise DataError(path, None, "model file not found")
    return path


def read_verified(model_dir, card: dict, card_path, name, field: str) -> tuple[Path, bytes]:
    """(path, bytes) of a file the card names, after its sha256 matched the card's."""
    path = confined(model_dir, name, card_path, field)
    want = card["sha256"].get(name)
    if want is None:
        raise DataError(card_path, f"sha256.{name}", "missing: every model file needs its checksum in the card")
    data = path.read_bytes()
    if hashlib.sha256(data).hexdigest() != want:
        raise DataError(path, None, "sha256 differs from the model card's: the file is damaged or was replaced")
    return path, data


def load_forests(model_dir, card: dict, card_path, roles=None) -> dict:
    """role -> fitted forest, for the card's `files` roles (all of them, or `roles`)."""
    files = card["files"]
    out = {}
    for role in roles or files:
        if role not in files:
            raise DataError(card_path, f"files.{role}", "missing")
        path, data = read_verified(model_dir, card, card_path, files[role], f"files.{role}")
        if role == "energy" and card.get("energy_model") == "linear":
            from .height_class import LinearHeightClass   # the linear estimate's plain arrays (height_class.py)

            out[role] = LinearHeightClass.load(path, data)
        else:
            out[role] = load_forest(path, data)
    return out


def verified_path(model_dir, card: dict, card_path, name, field: str) -> Path:
    """A file's path after its checksum matched (for readers that take a path, e.g. the site map)."""
    return read_verified(model_dir, card, card_path, name, field)[0]
