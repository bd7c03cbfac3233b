"""Checks the command line makes before any long computation: option values and output paths.

Every check raises :class:`~fgcal.errors.FgcalError` with one line naming the option or path.
Output paths are checked before the work starts (a typo in ``--out`` fails at once, not after
the solve), and an output may never replace a file the same run reads.
"""
from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

from fgcal.api.selection import MAX_BATCH_ROWS, MAX_POSES, parameter_names
from fgcal.cli.commands.inputs import DATASET_FILES, dataset_files, robot_files
from fgcal.cli.commands.options import count, finite, nonnegative, positive
from fgcal.errors import FgcalError
from fgcal.util.yamlio import may_replace, must_be_new

__all__ = [
    "DATASET_FILES",
    "MAX_BATCH_ROWS",
    "MAX_POSES",
    "check_output_dir",
    "check_output_file",
    "dataset_inputs",
    "finite_float",
    "nonnegative_float",
    "nonnegative_int",
    "os_error_message",
    "parameter_names",
    "positive_float",
    "positive_int",
]

# the option types of earlier rounds, now checked types of fgcal.cli.commands.options (kept for their importers)
finite_float = finite()
nonnegative_float = nonnegative()
positive_float = positive()
positive_int = count(1)
nonnegative_int = count(0)


def _same(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return Path(os.path.abspath(a)) == Path(os.path.abspath(b))


def _inside(child: Path, parent: Path) -> bool:
    c, p = Path(os.path.realpath(child)), Path(os.path.realpath(parent))
    return c == p or p in c.parents


def dataset_inputs(directory, robot: str | None = None) -> list[Path]:
    """The inputs of a run that reads the dataset ``directory`` (see :mod:`fgcal.cli.commands.inputs`): its
    folder, files and the robot file its ``dataset.yaml`` names; ``robot``, a robot reference
    relative to the folder, is added (the loaded dataset's, when dataset.yaml was unreadable before)."""
    return dataset_files(directory) + robot_files(robot, directory)


def _existing(path: Path, option: str):
    """``os.stat`` of ``path``, None when nothing is there; a dangling or looping link is an error."""
    if not os.path.lexists(path):
        return None
    try:
        return os.stat(path)
    except OSError as exc:
        raise FgcalError(f"{option} {path}: {exc.strerror or exc}") from None


def _writable_dir(folder: Path, option: str, target: Path) -> None:
    try:
        st = os.stat(folder)
    except FileNotFoundError:
        raise FgcalError(f"{option} {target}: folder {folder} does not exist") from None
    except OSError as exc:
        raise FgcalError(f"{option} {target}: folder {folder}: {exc.strerror or exc}") from None
    if not stat.S_ISDIR(st.st_mode):
        raise FgcalError(f"{option} {target}: {folder} is not a folder")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise FgcalError(f"{option} {target}: folder {folder} is not writable")


def check_output_file(path, inputs=(), option: str = "--out", force: bool | None = None) -> Path:
    """Check that ``path`` can be written as a file and replaces none of ``inputs``.

    The folder must exist and be writable; ``path`` must not be a folder or a special file.
    ``force``: False refuses to replace an existing file (the rule of every command with a
    ``--force`` option), True replaces it, None leaves that to the caller.
    """
    path = Path(path)
    if str(path) in ("", ".") or path.name in ("", ".", ".."):
        raise FgcalError(f"{option} {path}: not a file name")
    st = _existing(path, option)
    if st is not None:
        if stat.S_ISDIR(st.st_mode):
            raise FgcalError(f"{option} {path}: is a folder; give a file name")
        if not stat.S_ISREG(st.st_mode):
            raise FgcalError(f"{option} {path}: not a regular file (a device, FIFO or socket)")
    _writable_dir(path.parent, option, path)
    if st is not None and force is False and not any(src is not None and os.path.lexists(src)
                                                     and _same(path, Path(src)) for src in inputs):
        raise FgcalError(f"{path}: already exists (use --force to replace it)")
    for src in inputs:
        if src is not None and os.path.lexists(src) and _same(path, Path(src)):
            raise FgcalError(f"{option} {path}: is an input of this run ({src}); refusing to overwrite it")
    if force is False and st is None:
        must_be_new(path)
    elif force:
        may_replace(path)
    return path


def check_output_dir(path, inputs=(), option: str = "--out", must_be_new: bool = False, force: bool = False) -> Path:
    """Check that the folder ``path`` can be created (or written) and is not an input's folder.

    ``must_be_new``: ``path`` is replaced as a whole, so it must not exist unless ``force``.
    ``inputs`` are files or folders the run reads; ``path`` may neither be, nor contain, nor
    lie inside an input folder, nor contain an input file when it is replaced.
    """
    path = Path(path)
    if str(path) in ("", ".") and must_be_new:
        raise FgcalError(f"{option} {path}: not a new folder name")
    st = _existing(path, option)
    if st is not None:
        if not stat.S_ISDIR(st.st_mode):
            raise FgcalError(f"{option} {path}: exists and is not a folder")
        if must_be_new and not force:
            raise FgcalError(f"{path}: already exists (use --force to replace it)")
        if not must_be_new and not os.access(path, os.W_OK | os.X_OK):
            raise FgcalError(f"{option} {path}: folder is not writable")
        if not must_be_new and os.path.lexists(path / "dataset.yaml"):  # written into, it would mix with one
            raise FgcalError(f"{option} {path}: is a dataset folder; choose another folder")
    ancestor = path.parent if must_be_new or not os.path.lexists(path) else path
    while not os.path.lexists(ancestor) and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if ancestor != path:
        _writable_dir(ancestor, option, path)
    for src in inputs:
        if src is None or not os.path.lexists(src):
            continue
        src = Path(src)
        if src.is_dir() and (_inside(path, src) or _inside(src, path)):
            raise FgcalError(f"{option} {path}: overlaps the input folder {src}; choose another folder")
        if must_be_new and not src.is_dir() and _inside(src, path):
            raise FgcalError(f"{option} {path}: would replace the input {src}; choose another folder")
    return path


def os_error_message(exc: OSError) -> str:
    """One line for an operating-system error: the file(s) and what the system said."""
    what = exc.strerror or str(exc)
    if exc.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
        what += " (the disk is full or a file-size limit was reached; nothing was half-written)"
    names = [str(n) for n in (exc.filename, exc.filename2) if n is not None]
    return f"{' -> '.join(names)}: {what}" if names else what
