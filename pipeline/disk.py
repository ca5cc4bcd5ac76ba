"""Files the pipeline writes: temporary names a later run can clean up, and a full filesystem noticed
while it happens.

Every result file (the recording, the exports) is written to `.<name>.tmp-<pid>` beside its final
path and renamed when complete. A run killed by SIGKILL or a power cut cannot remove its own
temporary; the next run writing the same name removes those whose process is gone
(`remove_stale_temporaries`).

Rerun's file sink reports a failed write (a full disk) only in its own log and then drops the data,
so the run would go on for minutes and rename a truncated file over the earlier recording.
`DiskWatch` checks the free space of the folder once a second while the recording is written and,
when it falls under `MIN_FREE_BYTES`, raises `DiskFull` in the writing thread at once.
"""
from __future__ import annotations

import contextlib
import ctypes
import os
import re
import threading
from pathlib import Path

MIN_FREE_BYTES = 4 * 1024 * 1024   # twice the recording's 2 MB chunks: a flush that could not fit


def temporary_path(path: Path) -> Path:
    """Where `path` is written before it is renamed: `.<name>.tmp-<pid>` in the same folder."""
    return path.with_name(f".{path.name}.tmp-{os.getpid()}")


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:   # another user's process
        return True
    return True


def remove_stale_temporaries(path: Path) -> list[Path]:
    """Remove `.<name>.tmp-<pid>` (and the output check's `.<name>.probe-<pid>`) files beside `path`
    whose process no longer runs; returns what was removed. Another running process's are kept."""
    removed = []
    pattern = re.compile(re.escape(f".{path.name}.") + r"(?:tmp|probe)-(\d+)")
    try:
        entries = list(os.scandir(path.parent))
    except OSError:
        return removed
    for e in entries:
        m = pattern.fullmatch(e.name)
        if m and int(m.group(1)) != os.getpid() and not _alive(int(m.group(1))):
            with contextlib.suppress(OSError):
                if e.is_file(follow_symlinks=False):
                    os.unlink(e.path)
                    removed.append(Path(e.path))
    return removed


def free_bytes(folder: Path) -> int | None:
    """Bytes an unprivileged process may still write in `folder`'s filesystem (None: unknown)."""
    try:
        st = os.statvfs(folder)
    except (OSError, AttributeError):
        return None
    return st.f_bavail * st.f_frsize


class DiskFull(BaseException):
    """Raised in the writing thread by DiskWatch (a BaseException: no stage's `except Exception`
    may swallow it); `atomic_recording` turns it into a one-line InputError."""


class DiskWatch:
    """While active, checks the free space of `folder` every `interval` s; under MIN_FREE_BYTES it
    records the figure in `.low` and raises DiskFull in the thread that entered the watch."""

    def __init__(self, folder: Path, interval: float = 1.0, min_free: int | None = None):
        self.folder, self.interval = folder, interval
        self.min_free = MIN_FREE_BYTES if min_free is None else min_free
        self.low: int | None = None
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._armed = False
        self._target = 0
        self._thread: threading.Thread | None = None

    def __enter__(self):
        self._target = threading.get_ident()
        self._armed = True
        self._thread = threading.Thread(target=self._watch, name="disk-watch", daemon=True)
        self._thread.start()
        return self

    def _watch(self) -> None:
        while not self._stop.wait(self.interval):
            free = free_bytes(self.folder)
            if free is not None and free < self.min_free:
                with self._lock:
                    if self._armed:
                        self.low = free
                        ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(self._target),
                                                                   ctypes.py_object(DiskFull))
                return

    def __exit__(self, *exc) -> None:
        with self._lock:   # disarmed first: no DiskFull can arrive after this block
            self._armed = False
            if self.low is not None:   # raised but maybe not delivered yet: cancel it
                ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(self._target), None)
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
