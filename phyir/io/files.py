"""Files at the edge of the program: which paths may be read or written, atomic writes of one file
or a set of files, and the temporaries those writes use (docs/robustness.md, "Files, decoders,
output paths, signals").

* Inputs must be regular files (symlinks followed): a FIFO, a device, a socket or a folder is refused
  before it is opened, so nothing blocks on it; :func:`open_input` opens a file once, without blocking.
* Outputs must be new or regular files: :func:`check_output` refuses devices and folders.
* Temporaries are named ``.<name>.<pid>@<origin>-<8 hex>.phyir.tmp``: hidden and with no input's
  extension, so no folder reader takes one for an input (:func:`is_temporary`, :func:`folder_files`).
  ``<origin>`` names the machine and process-id namespace of the writer (:func:`origin`).  A write
  into a folder first removes the temporaries a killed process left there (:func:`sweep_stale`: at
  once when the writer was of this origin and its process is gone, e.g. after SIGKILL; otherwise
  when untouched for :data:`STALE_SECONDS`).
* Several outputs of one command are written as one set (:class:`AtomicSet`).
"""

from __future__ import annotations

import contextlib
import errno
import functools
import hashlib
import os
import re
import secrets
import signal
import socket
import stat
import threading
import time
from collections.abc import Iterable, Iterator
from typing import BinaryIO

from phyir.errors import InputError, PhyIRError, os_error, shown

TMP_SUFFIX = ".phyir.tmp"
STALE_SECONDS = 600  # a temporary untouched this long belongs to a process that died
# ours (".<name>.<pid>@<origin>-<hex>.phyir.tmp"), and those of earlier versions (no "@<origin>";
# ".<stem>.<hex>.tmp<ext>", which readers took for inputs)
_TEMPORARY = re.compile(r"\..+\.(?:(?P<pid>\d+)(?:@(?P<origin>[0-9a-f]{8}))?-)?[0-9a-f]{8}"
                        r"(?:\.phyir\.tmp|\.tmp(?:\.[A-Za-z0-9]+)?)")
_KINDS = ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a pipe (FIFO)"),
          (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
          (stat.S_ISSOCK, "a socket"))


def _kind(mode: int) -> str:
    return next((name for test, name in _KINDS if test(mode)), "not a regular file")


def _stat_error(p: str, e: OSError) -> InputError:
    if e.errno == errno.ELOOP:
        return InputError(p, "symlink loop (too many levels of symbolic links)")
    if e.errno == errno.ENOENT:
        return InputError(p, "no such file" + (" (a symlink to a missing file)" if os.path.islink(p) else ""))
    if e.errno == errno.ENOTDIR:
        return InputError(p, "no such file (a part of the path is not a folder)")
    if e.errno == errno.ENAMETOOLONG:
        return InputError(p, "file name too long")
    return InputError(p, f"cannot read: {e.strerror}")


def check_input(path: str | os.PathLike, what: str = "file") -> os.stat_result:
    """The stat of an input file; InputError unless it is a regular file (after symlinks)."""
    p = os.fspath(path)
    try:
        st = os.stat(p)
    except OSError as e:
        raise _stat_error(p, e) from None
    except ValueError:  # a NUL in the name
        raise InputError(p, "invalid file name (holds a NUL character)") from None
    if not stat.S_ISREG(st.st_mode):
        raise InputError(p, f"is {_kind(st.st_mode)}, not a regular {what}"
                            + (" (save the data to a file first)" if stat.S_ISFIFO(st.st_mode) else ""))
    return st


def open_input(path: str | os.PathLike, what: str = "file") -> BinaryIO:
    """Open a regular input file for reading, once: checked first, opened without blocking (a FIFO
    swapped in after the check is refused too), then read as an ordinary buffered file."""
    p = os.fspath(path)
    check_input(p, what)
    try:
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as e:
        raise _stat_error(p, e) from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise InputError(p, f"is {_kind(st.st_mode)}, not a regular {what}")
        os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def check_output(path: str | os.PathLike) -> None:
    """Refuse to write over anything but a regular file: a device, a FIFO, a folder."""
    p = os.fspath(path)
    try:
        st = os.stat(p)
    except FileNotFoundError:
        return
    except OSError as e:
        if e.errno == errno.ELOOP:
            raise InputError(p, "symlink loop (too many levels of symbolic links)") from None
        raise os_error(p, e) from None
    if not stat.S_ISREG(st.st_mode):
        raise InputError(p, f"is {_kind(st.st_mode)}: cannot write a file there")


# ---------------------------------------------------------------------------------------------
# temporaries


def is_temporary(name: str | os.PathLike) -> bool:
    """Whether a file name is one of atomic_write's temporaries (this version's or an earlier one's)."""
    return _TEMPORARY.fullmatch(os.path.basename(os.fspath(name))) is not None


def folder_files(folder: str | os.PathLike, suffixes: Iterable[str]) -> list[str]:
    """The regular, non-hidden files of ``folder`` with one of ``suffixes`` (lower case), sorted:
    what a command takes as its inputs from a folder (never a temporary)."""
    want = tuple(suffixes)
    out = []
    with os.scandir(folder) as it:
        for e in it:
            if e.name.startswith(".") or not e.name.lower().endswith(want):
                continue
            with contextlib.suppress(OSError):
                if e.is_file():
                    out.append(e.path)
    return sorted(out)


@functools.cache
def origin() -> str:
    """8 hex digits naming where this process's ids mean something: the machine (host name) and, on
    Linux, the process-id namespace (a container).  A temporary written under another origin (a
    folder shared over the network or with a container) holds a process id that cannot be checked."""
    ns = ""
    with contextlib.suppress(OSError, AttributeError):
        ns = os.readlink("/proc/self/ns/pid")
    return hashlib.blake2s(f"{socket.gethostname()}|{ns}".encode(), digest_size=4).hexdigest()


def _running(pid: int) -> bool | None:
    """Whether process ``pid`` runs; None where that cannot be asked (Windows: signal 0 is Ctrl-C)."""
    if os.name == "nt":
        return None
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # EPERM: someone else's process, alive
        return True
    return True


def sweep_stale(folder: str | os.PathLike, older_than: float = STALE_SECONDS) -> list[str]:
    """Remove the temporaries of our naming in ``folder`` that a dead process left.

    * written under this :func:`origin` and its process no longer runs: at once (a run killed with
      SIGKILL leaves nothing after the next write into its folder);
    * its process still runs (checked for this origin and for names of earlier versions): kept;
    * otherwise (another origin, a name of an earlier version): when untouched for ``older_than`` s."""
    removed = []
    now = time.time()
    with contextlib.suppress(OSError), os.scandir(folder) as it:
        for e in it:
            m = _TEMPORARY.fullmatch(e.name)
            if m is None:
                continue
            here = m["origin"] is None or m["origin"] == origin()  # an earlier name: was it here?
            alive = _running(int(m["pid"])) if m["pid"] and here else None
            if alive:
                continue
            with contextlib.suppress(OSError):
                st = e.stat(follow_symlinks=False)
                dead_here = alive is False and m["origin"] is not None
                if stat.S_ISREG(st.st_mode) and (dead_here or now - st.st_mtime > older_than):
                    os.remove(e.path)
                    removed.append(e.path)
    return removed


_DEFERRED = (signal.SIGINT, signal.SIGTERM) + ((signal.SIGHUP,) if hasattr(signal, "SIGHUP") else ())


@contextlib.contextmanager
def _signals_deferred() -> Iterator[None]:
    """SIGINT/SIGTERM/SIGHUP arriving inside the block take effect after it (the renames of a set)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    got: list[int] = []
    saved = {s: signal.signal(s, lambda n, _f: got.append(n)) for s in _DEFERRED}
    try:
        yield
    finally:
        for s, h in saved.items():
            signal.signal(s, signal.SIG_DFL if h is None else h)
        for s in got[:1]:
            signal.raise_signal(s)


class AtomicSet:
    """Files written as one set: :meth:`add` gives a temporary for each target (same folder, empty);
    leaving the ``with`` block normally syncs them and renames all (SIGINT/SIGTERM deferred during
    the renames), so a set of outputs (an EXR and its PNG, an animation's frames, GIF and stats, a
    report's JSON and Markdown) is never half old, half new.  If the block raises (KeyboardInterrupt
    and SIGTERM included) every temporary is removed and the targets are left untouched."""

    def __init__(self) -> None:
        self.pairs: list[tuple[str, str]] = []  # (temporary, target)
        self._swept: set[str] = set()

    def add(self, path: str | os.PathLike) -> str:
        target = os.fspath(path)
        check_output(target)
        if any(t == target for _, t in self.pairs):
            raise PhyIRError(f"{shown(target)}: written twice in one set")
        folder = os.path.dirname(os.path.abspath(target))
        if not os.path.isdir(folder):
            raise InputError(target, f"cannot write: folder {folder} does not exist")
        if folder not in self._swept:
            sweep_stale(folder)
            self._swept.add(folder)
        base = os.path.basename(target)
        for _ in range(100):
            tmp = os.path.join(folder, f".{base}.{os.getpid()}@{origin()}-{secrets.token_hex(4)}{TMP_SUFFIX}")
            try:
                with _signals_deferred():  # a signal between creating and recording it left it behind
                    os.close(os.open(tmp, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
                    self.pairs.append((tmp, target))
                return tmp
            except FileExistsError:
                continue
            except OSError as e:  # named as the user's file, not our temporary
                raise InputError(target, f"cannot write: {e.strerror}") from None
        raise PhyIRError(f"{target}: cannot create a temporary file in {folder}")  # pragma: no cover

    def commit(self) -> None:
        for tmp, _ in self.pairs:
            with open(tmp, "rb+") as f:
                os.fsync(f.fileno())
        with _signals_deferred():
            for tmp, target in self.pairs:
                os.replace(tmp, target)
        self.pairs = []

    def abort(self) -> None:
        for tmp, _ in self.pairs:
            with contextlib.suppress(FileNotFoundError):
                os.remove(tmp)
        self.pairs = []

    def __enter__(self) -> AtomicSet:
        return self

    def __exit__(self, kind, e, tb) -> None:
        pairs = list(self.pairs)
        if kind is None:
            try:
                self.commit()
                return
            except BaseException as err:
                e = err
                self.abort()
                raise self._named(e, pairs) from None
        self.abort()
        if isinstance(e, OSError):
            raise self._named(e, pairs) from None

    @staticmethod
    def _named(e: BaseException, pairs: list[tuple[str, str]]) -> BaseException:
        """An OSError naming the user's file, not our hidden temporary (or nothing: a full disk)."""
        if not isinstance(e, OSError) or not pairs or (e.filename is not None and
                                                      e.filename not in dict(pairs)):
            return e
        where = dict(pairs).get(e.filename) or (pairs[0][1] if len(pairs) == 1 else
                                                os.path.dirname(os.path.abspath(pairs[0][1])))
        return OSError(e.errno, e.strerror or str(e), where)


@contextlib.contextmanager
def atomic_files(paths: Iterable[str | os.PathLike]) -> Iterator[list[str]]:
    """:class:`AtomicSet` for a known list of targets: yields their temporaries, in order."""
    with AtomicSet() as files:
        yield [files.add(p) for p in paths]


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike) -> Iterator[str]:
    """Yield a temporary path next to ``path``; on success it replaces ``path`` atomically.

    The temporary (``.<name>.<pid>@<origin>-<random>.phyir.tmp``, same folder, so ``os.replace`` is a rename
    on one file system) exists and is empty when yielded.  If the block raises (including
    KeyboardInterrupt and SIGTERM, which the CLI turns into an exception) it is removed and ``path``
    is left untouched.
    """
    with AtomicSet() as files:
        yield files.add(path)


@contextlib.contextmanager
def input_stream(src, name: str | None = None) -> Iterator[tuple[BinaryIO, str]]:
    """``(file, name)`` of a path (checked and opened once, closed after) or of a file already open
    (rewound, left open): the readers take either, so a command opens each input once."""
    if hasattr(src, "read"):
        src.seek(0)
        yield src, name or str(getattr(src, "name", "<file>"))
        return
    p = os.fspath(src)
    with open_input(p) as f:
        yield f, name or p


def stream_size(f: BinaryIO) -> int:
    """The size in bytes of an open file."""
    try:
        return os.fstat(f.fileno()).st_size
    except (AttributeError, OSError, ValueError):  # in-memory files
        pos = f.tell()
        end = f.seek(0, os.SEEK_END)
        f.seek(pos)
        return end
