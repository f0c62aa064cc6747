"""A sweep's chunks: what each depends on, where its result lives, written whole.

A chunk is one controller over a contiguous range of worlds [start, stop). Its file
name carries a hash of everything its result depends on — the robot, the seed, the
range, the controller, the study's definition (:func:`study_key`: the durations, the
gains' range, the tolerances, a version) and the code (:func:`code_fingerprint`) — and
the file holds
that key too, checked on reading: a sweep run again with the same arguments finds its
finished chunks and computes only the rest; a changed parameter names other files, so an
old result is never taken for a new one. Files are written to a temporary name and
renamed (:mod:`qpik.rollout.io`): a chunk is on disk whole or not at all.
"""

from __future__ import annotations

import hashlib
import json
import zipfile
from dataclasses import dataclass
from functools import lru_cache
from importlib import metadata
from pathlib import Path

import numpy as np

from ...rollout.io import atomic_path
from .rollout import REACH_TOLERANCE
from .studies import DT, GAIN_RANGE, HOLD, MOVE, SAMPLE_BLOCK, steps_of

# Bump when what a chunk computes changes (a study's tasks, limits, sampling, metrics).
STUDY_VERSION = 1
NUMERICAL_PACKAGES = ("mujoco", "numpy", "daqp")


@lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """A digest of the code a chunk's result comes from: every source file of qpik, the
    bundled scenes, and the versions of MuJoCo, NumPy and DAQP. A result computed by
    other code (an edited qpik, an upgraded MuJoCo) may differ in its last bits, so it is
    not mixed into a sweep run with this code."""
    import qpik
    import qpik.scenes

    digest = hashlib.sha256()
    for root in (Path(qpik.__file__).parent, Path(qpik.scenes.__file__).parent):
        for path in sorted(p for p in root.rglob("*") if p.suffix in (".py", ".xml") and p.is_file()):
            digest.update(str(path.relative_to(root)).encode())
            digest.update(path.read_bytes())
    for name in NUMERICAL_PACKAGES:
        digest.update(f"{name}=={metadata.version(name)}".encode())
    return digest.hexdigest()[:16]


def study_key(move: float = MOVE, hold: float = HOLD) -> dict:
    """The study's definition, as a chunk's key holds it."""
    return {"version": STUDY_VERSION, "dt": DT, "steps": steps_of(move, hold), "move_s": move, "hold_s": hold,
            "gain_range": list(GAIN_RANGE), "sample_block": SAMPLE_BLOCK, "reach_tolerance_m": REACH_TOLERANCE}


CHUNK_FOLDER = "chunks"


@dataclass(frozen=True)
class Chunk:
    robot: str
    seed: int
    start: int
    stop: int
    controller: str
    move: float = MOVE
    hold: float = HOLD

    @property
    def worlds(self) -> int:
        return self.stop - self.start

    @property
    def steps(self) -> int:
        return steps_of(self.move, self.hold)

    def key(self) -> dict:
        return {"robot": self.robot, "seed": self.seed, "start": self.start, "stop": self.stop,
                "controller": self.controller, "study": study_key(self.move, self.hold), "code": code_fingerprint()}

    def digest(self) -> str:
        return hashlib.sha256(json.dumps(self.key(), sort_keys=True).encode()).hexdigest()[:16]

    def path(self, folder: Path) -> Path:
        return (Path(folder) / CHUNK_FOLDER /
                f"{self.robot}-{self.controller}-{self.start:010d}-{self.stop:010d}-{self.digest()}.npz")


def plan(robot: str, seed: int, targets: int, chunk: int, controllers: list[str], move: float = MOVE,
         hold: float = HOLD) -> list[Chunk]:
    """Every chunk of a sweep, range by range (each range's controllers together)."""
    return [Chunk(robot, seed, start, min(start + chunk, targets), controller, move, hold)
            for start in range(0, targets, chunk) for controller in controllers]


def write_chunk(folder: Path, chunk: Chunk, result: dict[str, np.ndarray], seconds: float = float("nan")) -> int:
    """Write a chunk's result whole (with its compute time); returns the file's size in bytes."""
    path = chunk.path(folder)
    with atomic_path(path) as tmp, open(tmp, "wb") as handle:
        np.savez_compressed(handle, _key=np.array(json.dumps(chunk.key(), sort_keys=True)),
                            _compute_s=np.array(seconds), **result)
    return path.stat().st_size


def read_chunk(folder: Path, chunk: Chunk) -> dict[str, np.ndarray] | None:
    """A finished chunk's result, or None (not computed, unreadable, or another key)."""
    path = chunk.path(folder)
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            if json.loads(str(data["_key"])) != json.loads(json.dumps(chunk.key(), sort_keys=True)):
                return None
            return {name: data[name] for name in data.files if not name.startswith("_")}
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError):
        return None


def compute_seconds(folder: Path, chunk: Chunk) -> float:
    """The compute time recorded with a finished chunk (s; NaN if none)."""
    try:
        with np.load(chunk.path(folder), allow_pickle=False) as data:
            return float(data["_compute_s"]) if "_compute_s" in data.files else float("nan")
    except (OSError, ValueError, zipfile.BadZipFile, EOFError):
        return float("nan")


def finished(folder: Path, chunks: list[Chunk]) -> set[Chunk]:
    """The chunks whose result is on disk (their files are read back to check them)."""
    return {c for c in chunks if read_chunk(folder, c) is not None}
