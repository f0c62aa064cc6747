"""``qpik sweep ROBOT --targets N``: the command-line side of a sweep.

The output folder keeps ``chunks/`` (every finished chunk, whole) and, once every chunk
is done, ``summary.json`` (no timings: the same for the same arguments however the chunks
ran), ``table.md``, ``timing.json`` and the workspace maps. Those final files are
assembled in a hidden folder and moved in together, shielded from Ctrl-C. Ctrl-C (130)
or SIGTERM (143) keeps the chunks finished so far; the same command resumes from them.
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ...errors import InvalidInput
from .studies import CONTROLLERS, DT, HOLD, MOVE, STUDIES, check_ported, ported

DEFAULT_CHUNK = 2048
DEFAULT_CONTROLLERS = "qp,pinv"
EXIT_INTERRUPTED, EXIT_TERMINATED = 130, 143
FINAL_FILES = ("summary.json", "table.md", "timing.json")


def _positive(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def _seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a duration in seconds, got {text!r}") from None
    if not (math.isfinite(value) and value >= DT):
        raise argparse.ArgumentTypeError(f"expected a duration of at least {DT:g} s, got {text}")
    return value


def _controllers(text: str) -> list[str]:
    names = [s.strip() for s in text.split(",") if s.strip()]
    unknown = [n for n in names if n not in CONTROLLERS]
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"unknown controller(s) {', '.join(unknown) or '(none given)'}; "
                                         f"choose from {', '.join(CONTROLLERS)}")
    if len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(f"a controller is named twice in {text!r}")
    return names


def chosen_controllers(robot: str, given: list[str] | None) -> list[str]:
    """The controllers to sweep: those given (each checked), else the defaults the engine
    runs for ``robot``.

    Raises:
        NotBatched: a controller given (or, with none ported, the first default) that needs
            a batched class the engine does not have yet.
    """
    if given is None:
        default = _controllers(DEFAULT_CONTROLLERS)
        given = [kind for kind in default if ported(robot, kind)] or default
    check_ported(robot, given)
    return given


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("robot", choices=sorted(STUDIES), help="the bundled robot to sweep")
    p.add_argument("--targets", type=_positive, required=True, metavar="N", help="number of worlds (targets)")
    p.add_argument("--controllers", type=_controllers, default=None, metavar="C1,C2",
                   help=f"comma-separated, of {', '.join(CONTROLLERS)} (default: {DEFAULT_CONTROLLERS}, those of them "
                        "the batched engine runs for ROBOT)")
    p.add_argument("--seed", type=int, default=0, help="seed of the samples (targets, start states, gains)")
    p.add_argument("--out", metavar="DIR", help="output folder; a sweep run again into it resumes "
                                                "(default: out/sweep-ROBOT)")
    p.add_argument("--ray", metavar="ADDRESS", help="run the chunks on Ray: auto starts a local cluster, an "
                                                    "address joins one (needs the ray extra)")
    p.add_argument("--chunk", type=_positive, default=DEFAULT_CHUNK, metavar="K", help="worlds per chunk")
    p.add_argument("--move", type=_seconds, default=MOVE, metavar="S",
                   help="seconds of the reference's quintic segment from the start to the target")
    p.add_argument("--hold", type=_seconds, default=HOLD, metavar="S", help="seconds the target is then held")
    p.add_argument("--workers", type=_positive, metavar="W",
                   help="with --ray: chunks at once (default: the cluster's CPUs)")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar")
    p.set_defaults(handler=cmd_sweep)


def check_folder(target: Path) -> None:
    """Refuse an output folder that is a file, holds other things, or cannot be written."""
    if target.exists() and not target.is_dir():
        raise InvalidInput(f"--out {target}: is an existing file, not a folder")
    if target.is_dir():
        entries = {p.name for p in target.iterdir()}
        if entries and "chunks" not in entries and "summary.json" not in entries:
            raise InvalidInput(f"--out {target}: holds files of something else; give an empty or new folder, "
                               "or a sweep's")
    existing = next(p for p in (target, *target.parents) if p.exists())
    if not existing.is_dir() or not os.access(existing, os.W_OK | os.X_OK):
        raise InvalidInput(f"--out {target}: {existing} cannot be written")


class Progress:
    """A tqdm bar (chunks done, robot-steps/s) on stderr, when wanted."""

    def __init__(self, enabled: bool, total: int, initial: int, robot: str, steps: int):
        self.bar = None
        self.per_world = steps
        self.steps = 0
        self.begin = time.perf_counter()
        if enabled:
            from tqdm import tqdm

            self.bar = tqdm(total=total, initial=initial, desc=f"sweep {robot}", unit="chunk", file=sys.stderr,
                            dynamic_ncols=True, leave=False)

    def update(self, worlds: int) -> None:
        self.steps += worlds * self.per_world
        if self.bar is not None:
            rate = self.steps / max(time.perf_counter() - self.begin, 1e-9)
            self.bar.set_postfix_str(f"{rate:,.0f} robot-steps/s", refresh=False)
            self.bar.update(1)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def cmd_sweep(args) -> int:
    from ..progress import wanted
    from .chunks import finished, plan

    if args.workers is not None and args.ray is None:
        raise InvalidInput("--workers applies to --ray only (in-process, the chunks run one after another)")
    args.controllers = chosen_controllers(args.robot, args.controllers)
    runner = None
    if args.ray is not None:
        from .runners import RayRunner

        runner = RayRunner(args.ray, args.workers)  # MissingExtra without Ray
    folder = Path(args.out or f"out/sweep-{args.robot}")
    check_folder(folder)
    chunks = plan(args.robot, args.seed, args.targets, args.chunk, args.controllers, args.move, args.hold)
    done = finished(folder, chunks)
    todo = [c for c in chunks if c not in done]
    folder.mkdir(parents=True, exist_ok=True)
    progress = Progress(wanted(args.quiet), len(chunks), len(done), args.robot, chunks[0].steps)
    log = Log(folder, len(done), args.interrupt_guard.shielded)
    begin = time.perf_counter()
    try:
        latency = _run(runner, todo, log, progress)
    except KeyboardInterrupt as exc:
        progress.close()
        from ..interrupt import Terminated

        terminated = isinstance(exc, Terminated)
        print(f"qpik: {'terminated' if terminated else 'interrupted'} with {log.kept} of {len(chunks)} chunks "
              f"finished, kept in {folder / 'chunks'}: the same command resumes from them", file=sys.stderr)
        return EXIT_TERMINATED if terminated else EXIT_INTERRUPTED
    progress.close()
    timing = log.timing(args, runner, latency, time.perf_counter() - begin, chunks)
    written = finish(folder, args, chunks, timing)
    print(f"wrote {', '.join(str(p) for p in written)}")
    return 0


def _run(runner, todo, log, progress) -> dict:
    def done(chunk, result, seconds):
        log.record(chunk, result, seconds)
        progress.update(chunk.worlds)

    if runner is None:
        from .runners import run_in_process

        run_in_process(todo, done)
        return {}
    with runner:
        return runner.run(todo, done)


class Log:
    """Writes each finished chunk whole and keeps its timing and sizes. ``shielded``: a
    context in which Ctrl-C and SIGTERM wait, so that a chunk is written or not at all and
    no temporary file is left behind."""

    def __init__(self, folder: Path, kept: int, shielded):
        self.folder, self.kept, self.shielded = folder, kept, shielded
        self.rows: list[dict] = []

    def record(self, chunk, result, seconds: float) -> None:
        from .chunks import write_chunk

        with self.shielded():
            size = write_chunk(self.folder, chunk, result, seconds)
        self.kept += 1
        self.rows.append({"controller": chunk.controller, "start": chunk.start, "stop": chunk.stop,
                          "steps": chunk.steps, "compute_s": seconds, "file_bytes": size,
                          "result_bytes": int(sum(v.nbytes for v in result.values()))})

    def timing(self, args, runner, latency: dict, wall: float, chunks: list) -> dict:
        from .chunks import compute_seconds

        computed = sum((r["stop"] - r["start"]) * r["steps"] for r in self.rows)
        recorded = [compute_seconds(self.folder, c) for c in chunks]
        for row in self.rows:
            key = [c for c in latency if (c.controller, c.start) == (row["controller"], row["start"])]
            if key:
                row["latency_s"] = latency[key[0]]
        return {"runner": "in-process" if runner is None else "ray", "ray": args.ray, "workers": args.workers,
                "chunk": args.chunk, "chunks": len(chunks), "chunks_computed": len(self.rows),
                "compute_s_every_chunk": float(np.nansum(recorded)),  # whichever run computed it
                "robot_steps": sum(c.worlds * c.steps for c in chunks),
                "wall_s": wall, "robot_steps_computed": computed,
                "robot_steps_per_s": computed / wall if wall > 0 else None,
                "load_average": list(os.getloadavg()), "cpus": os.cpu_count(), "per_chunk": self.rows}


def finish(folder: Path, args, chunks, timing: dict) -> list[Path]:
    """Write the summary, table, timing and maps together (staged, then moved in shielded)."""
    from ...extras import installed
    from ...rollout.io import write_json, write_text
    from .report import gather, summarize, to_markdown
    from .runners import _study

    targets, metrics = gather(folder, chunks, args.controllers)
    summary = summarize(args.robot, args.seed, args.controllers, metrics, _study(args.robot).template, args.move,
                        args.hold)
    table = to_markdown(summary)
    print(table, end="")
    staging = Path(tempfile.mkdtemp(prefix=".qpik-partial-", dir=folder))
    try:
        write_json(staging / "summary.json", summary)
        write_text(staging / "table.md", table)
        write_json(staging / "timing.json", timing)
        if installed("matplotlib"):
            from .figures import draw

            draw(staging, args.robot, targets, metrics, args.controllers)
        else:
            print("qpik: the workspace maps need matplotlib (the plots extra): not drawn", file=sys.stderr)
        with args.interrupt_guard.shielded():
            for old in folder.glob("workspace-*.png"):
                old.unlink()
            names = sorted(p.name for p in staging.iterdir())
            for name in names:
                os.replace(staging / name, folder / name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return [folder / name for name in names]
