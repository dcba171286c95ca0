"""How the project's programs answer bad input, and how they write files so nothing is half-written.

Every command-line program (quadson_mjx.cli.*, export, deploy, mcap_check) raises `UsageError` for
input it cannot run with and wraps its `main` in `one_line_errors`: the user sees one line on stderr
and the program exits with status 2, never a traceback. Files are written with `atomic_write`: to a
temporary file in the same folder, flushed and fsynced, then renamed over the target, so a reader
(or a crash) sees the old file or the whole new one.

Standard library only: this module sits at the bottom of the package and the robot's computer loads it.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import functools
import math
import os
import stat
import sys
import tempfile
from pathlib import Path

EXIT_USAGE = 2  # the status of a bad input, as argparse uses it


class UsageError(Exception):
    """Input a program cannot run with (a bad argument, a missing or damaged file, a config value out
    of range). The message is one line that names the input and, where there is one, the fix."""


class ArgumentParser(argparse.ArgumentParser):
    """argparse's parser whose errors (an unknown option, a value of the wrong type, a missing
    argument) raise UsageError instead of printing the usage and exiting: under one_line_errors the
    user sees one line, "error: MESSAGE (see PROG --help)", and exit status 2, like every other bad
    input. --help still prints the help and exits 0."""

    def error(self, message):
        raise UsageError(f"{message} (see {self.prog} --help)")

    def convert_arg_line_to_args(self, arg_line):
        """A line of an @file (a parser made with fromfile_prefix_chars="@"): its words, up to a '#'
        that starts a comment."""
        return arg_line.split("#", 1)[0].split()


def one_line(exc: BaseException) -> str:
    """The first line of an exception's message (its type's name when it has none)."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _os_hint(exc: OSError) -> str:
    where = f" {exc.filename}" if getattr(exc, "filename", None) else ""
    if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        return f"cannot write or read{where}: permission denied or read-only; choose a writable path"
    if exc.errno == errno.ENOSPC:
        return f"no space left on the device{where}; free some or choose another folder"
    if exc.errno == errno.ENOENT:
        return f"no such file or folder:{where or ' ' + one_line(exc)}"
    if exc.errno == errno.EISDIR:
        return f"{where.strip()} is a folder, a file is needed"
    if exc.errno == errno.ENOTDIR:
        return f"{where.strip()}: a path component is not a folder"
    return one_line(exc)


def one_line_errors(main):
    """Wrap a `main(argv=None) -> int`: a UsageError or an OSError (a missing, unreadable or
    unwritable file) prints one line "error: ..." on stderr and returns EXIT_USAGE. Other exceptions
    are bugs and keep their traceback."""

    @functools.wraps(main)
    def wrapped(*args, **kwargs):
        try:
            return main(*args, **kwargs)
        except UsageError as e:
            print(f"error: {one_line(e)}", file=sys.stderr)
            return EXIT_USAGE
        except OSError as e:
            print(f"error: {_os_hint(e)}", file=sys.stderr)
            return EXIT_USAGE

    return wrapped


@contextlib.contextmanager
def atomic_write(path, mode: str = "wb"):
    """Open a temporary file beside `path` for writing ("wb" or "w"); on a clean exit it is flushed,
    fsynced and renamed over `path`; on an exception it is removed and `path` is untouched. Raises
    UsageError before writing anything when the folder is missing or not writable."""
    path = Path(path)
    folder = _check_folder(path, "")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=folder)
    with contextlib.suppress(OSError):  # mkstemp makes 0600: give the mode a plain open would
        os.fchmod(fd, _new_file_mode(path))
    try:
        with os.fdopen(fd, mode) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def _new_file_mode(path: Path) -> int:
    """The mode `open(path, "w")` would leave: the file's own when it exists, else 0666 less the
    umask (read from /proc, since os.umask can only be read by setting it); 0644 if unknown."""
    with contextlib.suppress(OSError):
        return stat.S_IMODE(os.stat(path).st_mode)
    with contextlib.suppress(OSError, ValueError, IndexError):
        status = Path("/proc/self/status").read_text()
        umask = int(status.split("Umask:", 1)[1].split()[0], 8)
        return 0o666 & ~umask
    return 0o644


def write_bytes_atomic(path, data: bytes) -> None:
    with atomic_write(path, "wb") as f:
        f.write(data)


def write_text_atomic(path, text: str) -> None:
    with atomic_write(path, "w") as f:
        f.write(text)


def check_writable(path, what: str = "output") -> Path:
    """Raise UsageError now (before a long computation) when `path` could not be written later:
    missing or read-only folder, or a folder where a file is needed. -> Path(path)."""
    path = Path(path)
    _check_folder(path, f"{what} ")
    if path.exists() and not os.access(path, os.W_OK):
        raise UsageError(f"{what} {path}: not writable (read-only?); choose a writable path")
    return path


def _check_folder(path: Path, prefix: str) -> Path:
    """Raise UsageError (its message starting with prefix + path) when a file could not be created
    at `path`: a folder there, or its folder missing, a file, or not writable. -> the folder."""
    folder = path.parent if str(path.parent) else Path(".")
    if path.is_dir():
        raise UsageError(f"{prefix}{path} is a folder, a file name is needed")
    if folder.exists() and not folder.is_dir():
        raise UsageError(f"{prefix}{path}: {folder} is a file, not a folder")
    if not folder.is_dir():
        raise UsageError(f"{prefix}{path}: the folder {folder} does not exist; create it first")
    if not os.access(folder, os.W_OK):
        raise UsageError(f"{prefix}{path}: not writable (read-only?); choose a writable path")
    return folder


def make_folder(folder, what: str) -> Path:
    """Create `folder` and its parents; UsageError naming `what` (the argument) where it cannot be
    made. -> Path(folder)."""
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UsageError(f"{what} {folder}: cannot create it ({e.strerror or one_line(e)})") from None
    return folder


def check_readable(path, what: str = "input") -> Path:
    """Raise UsageError when `path` is not a readable file. -> Path(path)."""
    path = Path(path)
    if not path.exists():
        raise UsageError(f"{what} {path}: no such file")
    if path.is_dir():
        raise UsageError(f"{what} {path} is a folder, a file is needed")
    if not os.access(path, os.R_OK):
        raise UsageError(f"{what} {path}: not readable (permission denied)")
    return path


def check_run_dir(path, what: str = "--run") -> Path:
    """Raise UsageError when `path` is not a training run directory (a folder with config.json).
    -> Path(path)."""
    path = Path(path)
    if not (path / "config.json").is_file():
        raise UsageError(f"{what} {path}: not a training run directory (no config.json in it)")
    return path


def check_number(name: str, value, low: float = -math.inf, high: float = math.inf, *, above: bool = False):
    """Raise UsageError unless `value` is a finite number with low <= value <= high (low < value
    when `above`). `name` is the argument as the user typed it ("--seconds"). -> value."""
    v = float(value)
    ok = math.isfinite(v) and (v > low if above else v >= low) and v <= high
    if not ok:
        parts = []
        if low > -math.inf:
            parts.append(f"{'>' if above else '>='} {low:g}")
        if high < math.inf:
            parts.append(f"<= {high:g}")
        bound = f" {' and '.join(parts)}" if parts else ""
        raise UsageError(f"{name} {value}: must be a finite number{bound}")
    return value
