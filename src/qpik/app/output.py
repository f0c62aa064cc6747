"""A command's output folder, written all at once or not at all.

``qpik run``, ``compare`` and ``calibrate`` write several files (summary, log, figures,
video). They are assembled in a hidden staging folder beside the target and moved into
place only when every one is complete; an error or a Ctrl-C removes the staging folder,
so the target never holds half of a command's output.

An existing target is replaced whole, so no file of an earlier run survives beside the
new ones; only an empty folder or one qpik wrote (it holds one of ``OUTPUT_MARKERS``) is
replaced, any other folder is refused (``--out .`` must not empty the working folder).

The target is checked before any work: a path that names an existing file, a folder
qpik did not write, or a folder that cannot be written, is refused at once (the staging
folder is created right away, which is the real test of writability, also for root and
read-only mounts).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from contextlib import nullcontext
from pathlib import Path

from ..errors import InvalidInput

_STAGING_PREFIX = ".qpik-partial-"
_REPLACED_PREFIX = ".qpik-replaced-"
# The summary each command writes: a folder holding one is a qpik output folder.
OUTPUT_MARKERS = ("summary.json", "compare.json", "calibration.json")


def _nearest_existing(path: Path) -> Path:
    for candidate in (path, *path.parents):
        if candidate.exists():
            return candidate
    return Path(".")  # unreachable for a relative path: "." exists


def _replaceable(folder: Path) -> bool:
    """An empty folder, or one an earlier qpik command wrote."""
    entries = {p.name for p in folder.iterdir()}
    return not entries or any(marker in entries for marker in OUTPUT_MARKERS)


def _umask() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return umask


def _folder_mode() -> int:
    return 0o777 & ~_umask()


def _file_mode() -> int:
    return 0o666 & ~_umask()  # what open() gives; mkstemp makes 0600


class OutputFolder:
    """Stage a command's files next to ``target``; :meth:`commit` moves them in.

    Use as a context manager: leaving the block without :meth:`commit` (an error, a
    Ctrl-C) removes everything staged. ``guard`` (an
    :class:`~qpik.app.interrupt.InterruptGuard`) shields the commit and the clean-up
    from a Ctrl-C, so the move is never cut in half.

    Raises:
        InvalidInput: ``target`` is an existing file, lies under a file, or its folder
            cannot be written (one line, naming the path and the reason).
    """

    def __init__(self, target: str | Path, guard=None):
        self.target = Path(target)
        self._guard = guard
        self.staging: Path | None = None
        self._files: dict[Path, Path] = {}  # final path -> staged path, for files outside the folder
        if self.target.exists() and not self.target.is_dir():
            raise InvalidInput(f"--out {self.target}: is an existing file, not a folder")
        if self.target.is_dir() and not _replaceable(self.target):
            raise InvalidInput(f"--out {self.target}: an existing folder qpik did not write (no "
                               f"{', '.join(OUTPUT_MARKERS)}), which it would replace whole; "
                               "give a new or empty folder")
        # Staged beside the target (never inside it: an existing target is moved aside whole).
        anchor = _nearest_existing(self.target.absolute().parent)
        if not anchor.is_dir():
            raise InvalidInput(f"--out {self.target}: {anchor} is a file, not a folder")
        try:
            self.staging = Path(tempfile.mkdtemp(prefix=_STAGING_PREFIX, dir=anchor))
        except OSError as exc:
            raise InvalidInput(f"--out {self.target}: cannot write in {anchor} ({exc.strerror})") from None

    def add_file(self, final: str | Path) -> Path:
        """Stage one more output file at any path (e.g. ``--video FILE``), checked now like
        the folder and moved into place by the same :meth:`commit`; returns its staged path."""
        final = Path(final).absolute()
        if final.exists() and final.is_dir():
            raise InvalidInput(f"{final}: is a folder, expected a file name")
        if final.parent == self.target.absolute():
            staged = self.staging / final.name  # inside the output folder: staged with it
        else:
            anchor = _nearest_existing(final.parent)
            if not anchor.is_dir():
                raise InvalidInput(f"{final}: {anchor} is a file, not a folder")
            try:
                fd, name = tempfile.mkstemp(prefix=f".{final.name}.", suffix=final.suffix, dir=anchor)
            except OSError as exc:
                raise InvalidInput(f"{final}: cannot write in {anchor} ({exc.strerror})") from None
            os.close(fd)
            staged = Path(name)
        self._files[final] = staged
        return staged

    def file(self, final: str | Path) -> Path:
        """The staged path of a file registered with :meth:`add_file`."""
        return self._files[Path(final).absolute()]

    def path(self, name: str) -> Path:
        """Where to write output file ``name`` (inside the staging folder)."""
        return self.staging / name

    def commit(self) -> list[Path]:
        """Move every staged file into the target; returns their final paths."""
        with self._shield():
            outside = []
            for final, staged in self._files.items():
                if staged.parent != self.staging:
                    final.parent.mkdir(parents=True, exist_ok=True)
                    os.chmod(staged, _file_mode())
                    os.replace(staged, final)
                    outside.append(final)
            self._files.clear()
            names = sorted(p.name for p in self.staging.iterdir())
            replaced = None
            if self.target.is_dir():  # an earlier output: moved aside whole, removed after
                replaced = Path(tempfile.mkdtemp(prefix=_REPLACED_PREFIX, dir=self.target.parent))
                os.rename(self.target, replaced / self.target.name)
            self.target.parent.mkdir(parents=True, exist_ok=True)
            os.chmod(self.staging, _folder_mode())  # mkdtemp made it private (0700)
            try:
                os.rename(self.staging, self.target)
            except OSError:  # another file system between anchor and target
                shutil.move(str(self.staging), str(self.target))
            self.staging = None
            if replaced is not None:
                shutil.rmtree(replaced, ignore_errors=True)
        return [self.target / name for name in names] + outside

    def discard(self) -> None:
        """Remove the staging folder and every staged file."""
        with self._shield():
            for staged in self._files.values():
                if staged.exists() and (self.staging is None or staged.parent != self.staging):
                    staged.unlink()
            self._files.clear()
            if self.staging is not None:
                shutil.rmtree(self.staging, ignore_errors=True)
                self.staging = None

    def _shield(self):
        return self._guard.shielded() if self._guard is not None else nullcontext()

    def __enter__(self) -> OutputFolder:
        return self

    def __exit__(self, *exc) -> None:
        self.discard()
