"""One batch at a time per output folder: a lock file that the kernel releases when its owner dies.

The lock is ``fcntl.flock`` on ``OUTDIR/.pcdof-batch.lock``. The kernel drops it when the owning
process exits in any way (a crash or ``kill -9`` included), so a dead run never leaves the folder
stuck; the file itself holds the owner's pid, host and start time for the message a second run
gets. The owner removes the file when it finishes, and a run that takes the lock checks that the
file it locked is still the one under that name (the previous owner may have removed it meanwhile).
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import os
import socket

from ..errors import ImageWriteError, OutputInUseError
from .signals import signals_held

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX: no locking
    fcntl = None

LOCK_NAME = ".pcdof-batch.lock"
# folder (resolved) -> [fd, depth]: the locks this process holds (a held lock may be taken again, e.g. by
# render_sequence and then run_batch)
_HELD: dict[str, list[int]] = {}


def _owner(fd: int) -> str:
    try:
        os.lseek(fd, 0, os.SEEK_SET)
        info = json.loads(os.read(fd, 4096).decode("utf-8"))
        return f"pid {int(info['pid'])} on {info['host']!r}, started {info['started']}"
    except (OSError, ValueError, KeyError, TypeError):
        return "owner unknown"


def _acquire(folder: str) -> int:
    path = os.path.join(folder, LOCK_NAME)
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), 0o644)
        except OSError as err:
            raise ImageWriteError(f"cannot create the lock file {path!r}: {err.strerror or err}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            owner = _owner(fd)
            os.close(fd)
            raise OutputInUseError(f"the output folder {folder!r} is in use by another pcdof batch ({owner}); "
                                   "wait for it to finish or choose another output folder (-o)") from None
        except OSError as err:  # e.g. a file system without locks
            os.close(fd)
            raise ImageWriteError(f"cannot lock the output folder {folder!r}: {err.strerror or err}") from None
        try:
            current = os.stat(path).st_ino
        except FileNotFoundError:
            current = None
        if current == os.fstat(fd).st_ino:
            break
        os.close(fd)  # the previous owner removed the file between our open and flock: lock the new one
    info = {"pid": os.getpid(), "host": socket.gethostname(),
            "started": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")}
    os.ftruncate(fd, 0)
    os.write(fd, (json.dumps(info) + "\n").encode("utf-8"))
    return fd


@contextlib.contextmanager
def folder_lock(folder: str):
    """Hold the batch lock of the existing folder *folder* within the block.

    Raises
    ------
    OutputInUseError
        Another process holds it (the message names its pid, host and start time).
    ImageWriteError
        The lock file cannot be created or locked.
    """
    real = os.path.realpath(folder)
    if fcntl is None:
        yield
        return
    if real in _HELD:
        _HELD[real][1] += 1
        try:
            yield
        finally:
            _HELD[real][1] -= 1
        return
    # Ctrl-C or SIGTERM (as a batch raises them, pcdof.batch.signals) while the lock is taken or given back is
    # held until that is done: raised halfway, it would leave the lock file behind (or its descriptor open)
    taking = signals_held()
    taking.__enter__()
    try:
        fd = _acquire(real)
    except BaseException:
        taking.__exit__(None, None, None)
        raise
    _HELD[real] = [fd, 1]
    try:
        taking.__exit__(None, None, None)  # a signal held meanwhile raises here, and the lock is given back
        yield
    finally:
        with signals_held():
            del _HELD[real]
            with contextlib.suppress(OSError):
                os.unlink(os.path.join(real, LOCK_NAME))  # while still locked: the next owner re-checks the inode
            os.close(fd)
