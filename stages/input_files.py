"""Input files checked before they are opened: a regular file (not a folder, FIFO, device or socket:
a FIFO blocks the reader forever, /dev/zero never ends) of bounded size. Every problem is one line
naming the file; the check uses stat, never open."""
from __future__ import annotations

import os
import stat
from pathlib import Path

MAX_TEXT_BYTES = 4 * 1024 * 1024         # a scene, sweep or body file is a few kB
MAX_ASSET_BYTES = 2 * 1024 ** 3          # a character, mesh or glTF buffer: 2 GB is far beyond a real one


def file_kind(mode: int) -> str:
    """What a file that is not a regular one is, for a message ('a FIFO (named pipe)', ...)."""
    return ("a folder" if stat.S_ISDIR(mode) else "a FIFO (named pipe)" if stat.S_ISFIFO(mode) else
            "a character device" if stat.S_ISCHR(mode) else "a block device" if stat.S_ISBLK(mode) else
            "a socket" if stat.S_ISSOCK(mode) else "not a regular file")


def file_problem(path: Path, what: str, max_bytes: int | None = None) -> str | None:
    """Why `path` cannot be read as a `what` (missing, a folder, not a regular file, larger than
    `max_bytes`), or None."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return f"{what} not found"
    except OSError as e:
        return f"cannot read {what} ({e.strerror or e})"
    if stat.S_ISDIR(st.st_mode):
        return f"is a folder, expected a {what}"
    if not stat.S_ISREG(st.st_mode):
        return f"is {file_kind(st.st_mode)}, expected a {what} (a regular file)"
    if max_bytes is not None and st.st_size > max_bytes:
        return f"the {what} is {st.st_size:,} bytes, more than the limit of {max_bytes:,}"
    return None


def check_regular_file(path: Path, what: str, exc, *, max_bytes: int | None = None) -> None:
    """Raise exc(one line) unless `path` is an existing regular file of at most `max_bytes`."""
    problem = file_problem(path, what, max_bytes)
    if problem:
        raise exc(f"{path}: {problem}")


def read_bytes(path: Path, what: str, *, max_bytes: int = MAX_ASSET_BYTES, size: int | None = None) -> bytes:
    """The bytes of a regular file (at most `size` of them when given: a glTF buffer's byteLength),
    or an InputError(path, problem)."""
    from stages.errors import InputError
    problem = file_problem(path, what, max_bytes if size is None else None)
    if problem:
        raise InputError(path, problem)
    try:
        with open(path, "rb") as f:
            return f.read(max_bytes + 1 if size is None else size)
    except OSError as e:
        raise InputError(path, f"cannot read the {what} ({e.strerror or e})") from None


def read_text_file(path: Path, what: str, exc, *, max_bytes: int = MAX_TEXT_BYTES) -> str:
    """The text of a regular UTF-8 file of at most `max_bytes`, or exc(one line)."""
    check_regular_file(path, what, exc, max_bytes=max_bytes)
    try:
        with open(path, "rb") as f:
            raw = f.read(max_bytes + 1)
        if len(raw) > max_bytes:
            raise exc(f"{path}: the {what} is more than {max_bytes:,} bytes (expected a small text file)")
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise exc(f"{path}: cannot read {what}: not UTF-8 text (byte {e.start})") from None
    except OSError as e:
        raise exc(f"{path}: cannot read {what} ({e.strerror or e})") from None
