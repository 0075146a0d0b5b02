"""The one writer of the package's outputs: folders staged next to their place and swapped in whole, single
files written to a temporary name and renamed; nothing of the user's is ever deleted.

- `output_folder(path, force=False)` (a context manager) yields a fresh staging folder `.NAME.<pid>-<hex>.part`
  beside `path`. When the block ends normally the staging folder gets a manifest (`MANIFEST`: the name and
  sha256 of every entry the tool wrote) and takes `path`'s place in one atomic exchange (Linux renameat2
  RENAME_EXCHANGE; elsewhere two renames, undone on the next run if cut between them); the old folder is
  then removed. When the block raises, the staging folder is removed and `path` is as it was. A kill at any
  moment leaves either the old complete folder or the new complete one; the leftovers (staging folders of
  dead processes) are removed by the next write next to the same folder.
- "Written by the tool" means listed in the folder's manifest with the same content. A folder with anything
  else in it (a user's file, a file the user edited) is refused with an OutputError (exit 2) before any work
  is done, unless `force`: then the new entries are moved in one by one, a user's entry of the same name is
  kept as `NAME.replaced-<UTC time>`, and the user's other entries are left where they are.
- `atomic_file(path)` / `write_file(path, data)`: one file (caches, reports) written to `.NAME.<pid>-<hex>.part`
  beside it, fsync'd and renamed over it.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import hashlib
import json
import math
import os
import re
import secrets
import shutil
import time
from contextlib import contextmanager
from pathlib import Path

from .errors import ImpactSenseError

MANIFEST = ".impactsense-output.json"
_STAGE_MARK = ".impactsense-staging"
_LEFTOVER = re.compile(r"^\.(?P<name>.+)\.(?P<pid>\d+)-[0-9a-f]{8}\.(part|old)$")


class OutputError(ImpactSenseError):
    """An output place the tool may not write (a user's folder, a file where a folder goes)."""


# ----- hashing and manifests -----

def file_sha256(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def entry_sha256(path: Path) -> str:
    """A file's sha256; a folder's: over its files' relative paths and hashes (symlinks by their target)."""
    if path.is_symlink():
        return "link:" + os.readlink(path)
    if path.is_file():
        return file_sha256(path)
    h = hashlib.sha256()
    for p in sorted(path.rglob("*")):
        if p.is_file() or p.is_symlink():
            h.update(f"{p.relative_to(path).as_posix()}\0{entry_sha256(p)}\n".encode())
    return "tree:" + h.hexdigest()


def read_manifest(folder: Path) -> dict:
    try:
        raw = json.loads((folder / MANIFEST).read_text())
        files = raw.get("files") if isinstance(raw, dict) else None
        return {str(k): str(v) for k, v in files.items()} if isinstance(files, dict) else {}
    except (OSError, ValueError, AttributeError):
        return {}


def foreign_entries(folder: Path) -> list[str]:
    """The entries of an existing folder the tool did not write (or that changed since it did)."""
    listed = read_manifest(folder)
    out = []
    for p in sorted(folder.iterdir()):
        if p.name == MANIFEST:
            continue
        if p.name not in listed or entry_sha256(p) != listed[p.name]:
            out.append(p.name)
    return out


def _write_manifest(stage: Path, tool: str, extra: dict | None = None) -> None:
    files = {p.name: entry_sha256(p) for p in sorted(stage.iterdir()) if p.name not in (MANIFEST, _STAGE_MARK)}
    files.update(extra or {})
    body = {"written_by": tool, "written_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "files": files}
    (stage / MANIFEST).write_text(json.dumps(body, indent=1) + "\n")


# ----- leftovers of earlier runs -----

def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True
    return True


def clean_leftovers(path: Path) -> None:
    """Removes the staging folders/files of dead processes next to `path` (names `.NAME.<pid>-<hex>.part|old`).
    A leftover without the staging mark is an old output swapped out: only its manifest-listed entries are
    removed; anything else in it is moved back into `path` (or left where it is when the name is taken)."""
    parent = path.parent
    if not parent.is_dir():
        return
    for p in parent.iterdir():
        m = _LEFTOVER.match(p.name)
        if not m or m["name"] != path.name or _pid_alive(int(m["pid"])):
            continue
        if p.is_file() or p.is_symlink() or (p / _STAGE_MARK).exists():
            _remove(p)
            continue
        if not path.exists() and p.name.endswith(".old"):    # cut between the two renames: the old comes back
            os.rename(p, path)
            continue
        _remove_ours(p, path)


def _remove_ours(old: Path, home: Path) -> None:
    """Deletes the entries of `old` its manifest lists unchanged; moves the others into `home`."""
    listed = read_manifest(old)
    for p in list(old.iterdir()):
        if p.name == MANIFEST:
            continue
        if p.name in listed and entry_sha256(p) == listed[p.name]:
            _remove(p)
        elif home.is_dir() and not (home / p.name).exists():
            os.rename(p, home / p.name)
    # the manifest goes last: a run killed in this loop leaves a folder the next run still knows as ours
    (old / MANIFEST).unlink(missing_ok=True)
    try:
        old.rmdir()
    except OSError:
        pass    # a user's file is still in it: kept


def _remove(p: Path) -> None:
    if p.is_dir() and not p.is_symlink():
        shutil.rmtree(p, ignore_errors=True)
    else:
        p.unlink(missing_ok=True)


# ----- the atomic exchange -----

_libc = None


def _exchange(a: Path, b: Path) -> bool:
    """Atomically swaps two paths (Linux renameat2 RENAME_EXCHANGE); False where the system has none."""
    global _libc
    if _libc is None:
        try:
            _libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
            _libc.renameat2  # noqa: B018  (AttributeError where missing)
        except (OSError, AttributeError):
            _libc = False
    if not _libc:
        return False
    at_fdcwd, rename_exchange = -100, 2
    rc = _libc.renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange)
    if rc != 0:
        err = ctypes.get_errno()
        if err in (22, 38, 95):   # EINVAL, ENOSYS, EOPNOTSUPP: this filesystem cannot exchange
            return False
        raise OSError(err, os.strerror(err), str(b))
    return True


def _fsync_path(p: Path) -> None:
    """fsync a file or folder, best effort (a path that cannot be opened or synced is left as it is)."""
    try:
        fd = os.open(p, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _fsync_tree(folder: Path) -> None:
    for p in [*folder.rglob("*"), folder]:
        if not p.is_symlink():
            _fsync_path(p)


def _stage_name(path: Path, kind: str = "part") -> Path:
    return path.parent / f".{path.name}.{os.getpid()}-{secrets.token_hex(4)}.{kind}"


def check_output_folder(path: str | os.PathLike, force: bool = False) -> Path:
    """Raises OutputError unless `path` may be written (absent, empty, the tool's own, or force)."""
    path = Path(path)
    clean_leftovers(path)
    if path.exists() or path.is_symlink():
        if not path.is_dir():
            raise OutputError(f"{path}: exists and is not a folder; nothing was written")
        if not force:
            foreign = foreign_entries(path)
            if foreign:
                shown = ", ".join(foreign[:5]) + (" ..." if len(foreign) > 5 else "")
                raise OutputError(f"{path}: the folder holds files impactsense did not write ({shown}); "
                                  "choose another folder, or add --force to write into it (your files are "
                                  "kept; one with the name of an output is renamed NAME.replaced-<time>)")
    return path


@contextmanager
def output_folder(path: str | os.PathLike, force: bool = False, tool: str = "impactsense"):
    """Yields a staging folder; on normal exit it becomes `path` (see the module doc)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    check_output_folder(path, force)
    stage = _stage_name(path)
    stage.mkdir()
    (stage / _STAGE_MARK).touch()
    try:
        yield stage
        _commit(stage, path, force, tool)
    except BaseException:
        if stage.exists():
            _remove(stage)
        raise


def _commit(stage: Path, path: Path, force: bool, tool: str) -> None:
    check_output_folder(path, force)     # again: the folder may have changed while the work ran
    merge = path.is_dir() and bool(foreign_entries(path))
    if merge:
        _merge_into(stage, path, tool)
        return
    _write_manifest(stage, tool)
    (stage / _STAGE_MARK).unlink()
    _fsync_tree(stage)
    if not path.exists():
        os.rename(stage, path)
    elif _exchange(stage, path):
        _remove_ours(stage, path)        # stage now holds the old output
    else:
        old = _stage_name(path, "old")
        os.rename(path, old)
        os.rename(stage, path)
        _remove_ours(old, path)
    _fsync_path(path.parent)


def _merge_into(stage: Path, path: Path, tool: str) -> None:
    """--force into a folder with a user's entries: ours replace ours; a user's entry of the same name is
    renamed NAME.replaced-<time>; the user's other entries stay."""
    listed = read_manifest(path)
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    ours_now = {}
    for entry in sorted(p for p in stage.iterdir() if p.name != _STAGE_MARK):
        target = path / entry.name
        if target.exists() or target.is_symlink():
            if entry.name in listed and entry_sha256(target) == listed[entry.name]:
                aside = _stage_name(target, "old")
                os.rename(target, aside)
                os.rename(entry, target)
                _remove(aside)
            else:
                os.rename(target, path / f"{entry.name}.replaced-{stamp}")
                os.rename(entry, target)
        else:
            os.rename(entry, target)
        ours_now[entry.name] = entry_sha256(target)
    kept = {k: v for k, v in listed.items() if (path / k).exists() and k not in ours_now}
    tmp = path / f".{MANIFEST}.{os.getpid()}.part"
    tmp.write_text(json.dumps({"written_by": tool, "files": {**kept, **ours_now}}, indent=1) + "\n")
    os.replace(tmp, path / MANIFEST)
    _remove(stage)


def adopt(folder: str | os.PathLike, names) -> None:
    """Adds the named entries of `folder` (written by the tool in place, e.g. `demo`'s) to its manifest."""
    folder = Path(folder)
    listed = read_manifest(folder)
    listed.update({n: entry_sha256(folder / n) for n in names if (folder / n).exists()})
    write_file(folder / MANIFEST, json.dumps({"written_by": "impactsense", "files": listed}, indent=1) + "\n")


def finite_or_none(obj):
    """obj with every NaN/inf float (numpy's too) replaced by None, for strict JSON."""
    if isinstance(obj, dict):
        return {k: finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_or_none(v) for v in obj]
    if hasattr(obj, "tolist") and not isinstance(obj, (str, bytes)):
        return finite_or_none(obj.tolist())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def json_text(obj, indent: int = 1) -> str:
    """Strict JSON (NaN written as null)."""
    return json.dumps(finite_or_none(obj), indent=indent, allow_nan=False) + "\n"


# ----- single files -----

@contextmanager
def atomic_file(path: str | os.PathLike, mode: str = "wb"):
    """Yields an open file at a temporary name beside `path`; on normal exit fsync'd and renamed over it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    clean_leftovers(path)
    tmp = _stage_name(path)
    try:
        with open(tmp, mode) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_file(path: str | os.PathLike, data: bytes | str) -> Path:
    """`data` into `path`, atomically (atomic_file)."""
    with atomic_file(path, "wb") as fh:
        fh.write(data.encode() if isinstance(data, str) else data)
    return Path(path)
