"""Every file capsim writes goes through here: output guards, locks, temporary names,
atomic replacement, room checks and the identity of an open file.

The rules (docs/data_safety.md):

- Nothing a command did not create is removed, truncated or replaced unless the user
  says ``--overwrite``; never a command's own input; never a directory, a device, a
  pipe or a socket, and never a file through a symbolic link (the link is refused,
  its target is never written).
- Every change to an existing file is made on a temporary copy next to it and moved
  into place with one ``rename``: a failure (a full disk, a file-size limit, a kill)
  leaves the file as it was.
- A lock is a capsim-named hidden file next to what it guards
  (``.<name>.capsim-lock``, opened without following links), held with ``flock``:
  the kernel drops it when its process dies, and no user file can be taken for it.

Errors are :class:`OutputError` (one line; the CLI turns it into exit 2),
:class:`LockedError` and :class:`StorageError`. Numba-, h5py- and pydantic-free.
"""

from __future__ import annotations

import errno
import fcntl
import os
import resource
import shutil
import stat
from pathlib import Path
from typing import Callable

from capsim.errors import first_line

__all__ = [
    "FileIdentity", "FileLock", "LockedError", "OutputError", "StorageError",
    "check_writable", "copy_and_replace", "free_bytes", "guard_output", "lock_path", "mb",
    "ladder_work_path", "remove_stale_ladder_files", "replace_atomically", "room_bytes", "same_file", "tmp_name",
    "write_durably", "write_failure",
]


class OutputError(Exception):
    """An output path that a command must not write (exists, is an input, is not a
    regular file, cannot be written); one line naming the path and what to do."""


class LockedError(Exception):
    """Another process holds the file (a run file, a campaign directory); one line naming it."""


class StorageError(Exception):
    """Writing failed (a full disk, a file-size limit, an I/O error); one line naming the file."""


def write_failure(path: str | os.PathLike, exc: BaseException) -> str:
    """'<path>: cannot write: <reason>' in one line (strerror of an OSError, else its first line)."""
    reason = getattr(exc, "strerror", None) or (str(exc)[:400].splitlines() or [type(exc).__name__])[0]
    return f"{os.fspath(path)}: cannot write: {reason}"


def mb(n: float) -> str:
    return f"{max(n, 0) / 1e6:.2f} MB"


# ---------------------------------------------------------------- names


def tmp_name(path: str | os.PathLike) -> Path:
    """The one temporary name of capsim: ``.<stem>.tmp-<pid><suffix>`` next to `path`
    (hidden, private to this process, with the suffix that picks a file format)."""
    path = Path(path)
    return path.with_name(f".{path.stem}.tmp-{os.getpid()}{path.suffix}")


def lock_path(path: str | os.PathLike) -> Path:
    """The lock of a file, ``.<name>.capsim-lock`` beside it; of a directory, ``<dir>/.capsim.lock``."""
    path = Path(path)
    return path / ".capsim.lock" if path.is_dir() else path.with_name(f".{path.name}{LOCK_SUFFIX}")


#: a measured accuracy target's level file beside its output, ``.<run>.h5.ladder-<pid>.h5`` (capsim.runs.ladder)
LADDER_INFIX = ".ladder-"


def ladder_work_path(out: str | os.PathLike) -> Path:
    """Where this process's ladder runs its levels for output `out`: hidden, beside it (one file
    system: a completed level is renamed over the output), named with this process's id."""
    out = Path(out)
    return out.with_name(f".{out.name}{LADDER_INFIX}{os.getpid()}.h5")


def pid_alive(pid: int) -> bool:
    """Whether a process of this id exists on this host (one of another user's counts)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    except (OverflowError, ValueError, OSError):
        return False
    return True


def remove_stale_ladder_files(out: str | os.PathLike) -> list[Path]:
    """Remove what a ladder killed outright (``kill -9``, the out-of-memory killer) left beside
    `out`: its level file, that file's checkpoint, lock and temporary copies, all named
    ``.<run>.h5.ladder-<pid>…`` or ``..<run>.h5.ladder-<pid>…``. Only of a process that no longer
    exists, only regular files, and only once that level file's own lock could be taken (a live
    writer, even one this host cannot see, holds it). The caller holds `out`'s lock, which every
    ladder on `out` holds from start to end: no live ladder on `out` can be writing these.
    Returns the paths removed."""
    out = Path(out)
    prefix = f".{out.name}{LADDER_INFIX}"
    try:
        names = os.listdir(out.parent)
    except OSError:
        return []
    by_pid: dict[int, list[Path]] = {}
    for name in names:
        rest = name[len(prefix):] if name.startswith(prefix) else name[len(prefix) + 1:] \
            if name.startswith("." + prefix) else None
        digits = rest.split(".", 1)[0] if rest else ""
        if digits.isdigit() and len(digits) < 12:
            by_pid.setdefault(int(digits), []).append(out.with_name(name))
    removed: list[Path] = []
    for pid, paths in sorted(by_pid.items()):
        if pid == os.getpid() or pid_alive(pid):
            continue
        work = out.with_name(f"{prefix}{pid}.h5")
        try:
            lock = FileLock(work, what="ladder level file").acquire()
        except (LockedError, StorageError):
            continue  # held: a writer lives, wherever it runs
        try:
            for path in paths:
                if path == lock.path:
                    continue  # removed by the release, as the file this process locked
                try:
                    if stat.S_ISREG(os.lstat(path).st_mode):
                        path.unlink()
                        removed.append(path)
                except OSError:
                    pass
        finally:
            lock.release()
        removed.extend(p for p in paths if p == lock.path and not os.path.lexists(p))
    return removed


# ---------------------------------------------------------------- room


def free_bytes(path: str | os.PathLike) -> int:
    """Free bytes for an unprivileged writer on the file system holding `path` (or its nearest existing parent)."""
    p = Path(path)
    while not p.exists() and p != p.parent:
        p = p.parent
    return shutil.disk_usage(p).free


def room_bytes(path: str | os.PathLike, size: int = 0) -> float:
    """Bytes a file of `size` bytes in directory `path` may still grow by: the file
    system's free space, capped by this process's RLIMIT_FSIZE."""
    soft, _ = resource.getrlimit(resource.RLIMIT_FSIZE)
    limit = float("inf") if soft == resource.RLIM_INFINITY else float(soft)
    return min(float(free_bytes(path)), limit - size)


def require_room(path: str | os.PathLike, need: float, what: str) -> None:
    """StorageError (one line, nothing changed) when fewer than `need` bytes may be
    written next to `path` (free space, or the file-size limit for one file of `need`)."""
    room = room_bytes(Path(path).parent)
    if room < need:
        raise StorageError(f"{os.fspath(path)}: cannot write: {mb(room)} of room on its file system (or under the "
                           f"file-size limit), {what} needs {mb(need)}; nothing was changed")


# ---------------------------------------------------------------- guards


def same_file(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def _kind_of(path: Path) -> str | None:
    """What an existing path is that no command writes, even with --overwrite; None for a regular file."""
    try:
        st = os.lstat(path)
    except OSError:  # absent, or a parent that is not a directory: the later checks say which
        return None
    if stat.S_ISLNK(st.st_mode):
        return "a symbolic link (capsim never writes through one: give the path it points to)"
    if stat.S_ISDIR(st.st_mode):
        return "a directory"
    if not stat.S_ISREG(st.st_mode):
        return "not a regular file (a device, a pipe or a socket)"
    return None


def check_writable(path: str | os.PathLike) -> None:
    """Refuse an output path we cannot write before spending time on a run: a directory,
    a non-regular file, a link, a path too long, a directory we cannot create or write."""
    path = Path(path)
    try:
        kind = _kind_of(path)
        if kind is not None:
            raise OutputError(f"output path {path} is {kind}")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OutputError(f"output path {path}: cannot create its directory {path.parent}: "
                              f"{exc.strerror or first_line(exc)}") from None
        if not os.access(path.parent, os.W_OK) or (path.exists() and not os.access(path, os.W_OK)):
            raise OutputError(f"output path {path} is not writable")
        # a name the file system refuses (ENAMETOOLONG) is found here, not after a run
        if len(os.fsencode(tmp_name(path).name)) > os.pathconf(path.parent, "PC_NAME_MAX"):
            raise OutputError(f"output path {path}: its file name is longer than the file system allows")
    except OSError as exc:  # ENAMETOOLONG, ELOOP, ...
        raise OutputError(f"output path {str(path)[:200]}: {exc.strerror or first_line(exc)}") from None


#: the name of a run's restart checkpoint beside it (capsim.storage.checkpoint owns its content)
CHECKPOINT_SUFFIX = ".ckpt.npz"
#: the name of a lock beside the file it guards
LOCK_SUFFIX = ".capsim-lock"

#: a campaign directory's own files (capsim.campaigns.campaign writes them; named here, where every guard sees them)
INDEX_FILE = "runs.json"
CAMPAIGN_FILE = "campaign.yaml"

def is_run_file(path: str | os.PathLike) -> bool:
    """Whether `path` is a capsim run file (an HDF5 file with a stored case), however damaged its arrays."""
    import h5py  # here, not at the top: the guards of a --help need no HDF5

    try:
        if not os.path.isfile(path) or not h5py.is_hdf5(path):
            return False
        with h5py.File(path, "r", locking=False) as f:
            return "config_yaml" in f.attrs
    except (OSError, ValueError):
        return False


def _root_attrs(path: str | os.PathLike) -> set[str]:
    """The root attribute names of an HDF5 (netCDF-4) file; empty when it is none."""
    import h5py

    try:
        with h5py.File(path, "r", locking=False) as f:
            return set(f.attrs)
    except (OSError, ValueError):
        return set()


def is_summary_file(path: str | os.PathLike) -> bool:
    """A netCDF file written by `capsim summarize` (its campaign_yaml attribute, no config_yaml)."""
    attrs = _root_attrs(path)
    return "campaign_yaml" in attrs and "config_yaml" not in attrs


def is_study_file(path: str | os.PathLike) -> bool:
    """A netCDF file written by `capsim study` (its reference and error_definition attributes)."""
    return {"error_definition", "reference"} <= _root_attrs(path)


#: the first bytes of a figure of each format: an existing file that starts so is one capsim may redraw
FIGURE_MAGIC = {"png": b"\x89PNG\r\n\x1a\n", "pdf": b"%PDF-", "svg": b"<?xml"}

#: the first bytes of an HDF5 file (a run file; capsim writes no user block before them)
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def is_hdf5(path: str | os.PathLike) -> bool:
    """Whether `path` is a readable file that starts as an HDF5 file does (without loading h5py)."""
    try:
        if not os.path.isfile(path):  # a FIFO or a device would block or stream: not a run file
            return False
        with open(path, "rb") as fh:
            return fh.read(len(HDF5_SIGNATURE)) == HDF5_SIGNATURE
    except (OSError, ValueError):
        return False


def protected(path: Path) -> str | None:
    """What an existing file is that no command replaces unless told to (--overwrite); None if not one."""
    if path.name in (CAMPAIGN_FILE, INDEX_FILE):
        return "a campaign's own file"
    if path.name.endswith(CHECKPOINT_SUFFIX):
        return "a restart checkpoint"
    if is_run_file(path):
        return "a capsim run file"
    return None


def guard_output(out: str | os.PathLike, inputs: list, overwrite: bool, *,
                 ours: Callable[[Path], bool] = lambda p: False, option: str = "--overwrite") -> None:
    """Refuse (:class:`OutputError`) to write over one of the command's inputs (never),
    over a link, a directory or a non-regular file (never), or over an existing file
    it does not write itself (``ours``) or that is a run file, a checkpoint or a
    campaign file, unless `overwrite`."""
    out = Path(out)
    for source in inputs:
        if same_file(out, Path(source)):
            raise OutputError(f"output path {out} is this command's input {source}; choose another output")
    kind = _kind_of(out)
    if kind is not None:
        raise OutputError(f"output path {out} is {kind}; nothing was changed: choose another output")
    if os.path.lexists(out) and not overwrite:
        what = protected(out)
        if what is not None or not ours(out):
            raise OutputError(f"output path {out} exists ({what or 'a file this command did not write'}); "
                              f"nothing was changed: choose another output, or pass {option} to replace it")


def starts_with(magic: bytes) -> Callable[[Path], bool]:
    """``ours`` for guard_output: a file that starts with `magic` (a figure format's signature)."""
    def check(path: Path) -> bool:
        try:
            with open(path, "rb") as fh:
                return fh.read(len(magic)) == magic
        except OSError:
            return False
    return check


# ---------------------------------------------------------------- atomic writes


def replace_atomically(out: str | os.PathLike, write: Callable[[Path], None]) -> None:
    """``write(tmp)`` to :func:`tmp_name` next to `out`, then move it into place: a
    failure (a full disk, a size limit) leaves `out` as it was and raises StorageError."""
    out = Path(out)
    tmp = tmp_name(out)
    try:
        write(tmp)
        os.replace(tmp, out)
    except (OSError, RuntimeError, StorageError) as exc:
        tmp.unlink(missing_ok=True)
        text = str(exc) if isinstance(exc, StorageError) else getattr(exc, "strerror", None) or first_line(exc)
        raise StorageError(f"cannot write {out}: {first_line(StorageError(text))}; nothing was changed") from None
    finally:
        tmp.unlink(missing_ok=True)


def write_durably(path: str | os.PathLike, write: Callable, kept: str) -> None:
    """``write(fh)`` into :func:`tmp_name` opened for binary writing, fsync, rename over
    `path`: a reader never sees half a file and a crash after it returns loses nothing.
    A failure (a full disk) leaves `path` as it was: StorageError, '<path>: cannot write:
    <reason>; <kept>'."""
    path = Path(path)
    tmp = tmp_name(path)
    try:
        with open(tmp, "wb") as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise StorageError(f"{write_failure(path, exc)}; {kept}") from None


def copy_and_replace(path: str | os.PathLike, change: Callable[[Path], None], headroom: int) -> None:
    """Change an existing file on a copy: copy it to :func:`tmp_name`, ``change(copy)``,
    rename the copy over it. Refused first when there is not room for the copy and
    `headroom` bytes more. Any failure leaves the file as it was (StorageError)."""
    path = Path(path)
    size = os.path.getsize(path)
    room = room_bytes(path.parent) - size  # capped by the file-size limit too
    if room < headroom:
        raise StorageError(f"{path}: cannot write: {mb(room)} of room beyond a copy of the file on its file "
                           f"system (or under the file-size limit), {mb(headroom)} needed; nothing was changed")

    def write(tmp: Path) -> None:
        shutil.copyfile(path, tmp)
        change(tmp)

    replace_atomically(path, write)


# ---------------------------------------------------------------- identity


class FileIdentity:
    """The device and inode of a file as it was opened: :meth:`check` raises
    StorageError once the path names another file (deleted, replaced by another run)."""

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        st = os.stat(self.path)
        self.key = (st.st_dev, st.st_ino)

    def check(self) -> None:
        try:
            st = os.stat(self.path)
            now = (st.st_dev, st.st_ino)
        except FileNotFoundError:
            now = None
        if now != self.key:
            what = "was deleted" if now is None else "was replaced by another file"
            raise StorageError(f"{self.path}: the run file {what} while the run was writing it; "
                               "the run stopped (its rows went with the file)")


# ---------------------------------------------------------------- locks


class FileLock:
    """An exclusive, non-blocking ``flock`` on ``lock_path(path)``, taken before the
    guarded file is touched and held until release (the kernel drops it when the
    process dies, SIGKILL included). A second holder gets :class:`LockedError`.

    The lock file is capsim's by its name, opened without following a link (a link
    there is refused, its target untouched), and removed on release only if it is
    still the file this process locked; a process that opened it just before it was
    removed notices (its file is no longer the one at the path) and retries.
    """

    def __init__(self, path: str | os.PathLike, what: str = "run file") -> None:
        self.target, self.what = Path(path), what
        self.path = lock_path(path)
        self._fd: int | None = None

    def acquire(self) -> FileLock:
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise StorageError(f"{self.path.parent}: cannot create the directory: {exc.strerror}") from None
        for _ in range(100):
            try:
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)
            except OSError as exc:
                if exc.errno == errno.ELOOP:
                    raise LockedError(f"{self.target}: its lock {self.path} is a symbolic link, not capsim's; "
                                      "nothing was changed (remove the link)") from None
                raise StorageError(f"{self.target}: cannot take the lock {self.path}: "
                                   f"{exc.strerror or first_line(exc)}") from None
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                os.close(fd)
                raise LockedError(f"{self.target}: its lock {self.path} is not a regular file; nothing was changed")
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as exc:
                os.close(fd)
                if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    holder = ""
                    try:
                        with open(self.path, "rb", opener=lambda p, f: os.open(p, f | os.O_NOFOLLOW)) as fh:
                            holder = fh.read(20).decode("ascii", "replace").strip()
                    except OSError:
                        pass
                    by = f" (process {holder})" if holder.isdigit() else ""
                    raise LockedError(
                        f"{self.target}: {self.what} in use by another capsim process{by}; "
                        "nothing was changed (wait for it to end, or stop it)"
                    ) from None
                raise StorageError(f"{self.target}: cannot take the lock {self.path}: {exc.strerror}") from None
            if self._same(fd):
                self._fd = fd
                try:
                    os.ftruncate(fd, 0)
                    os.write(fd, str(os.getpid()).encode())
                except OSError:  # a full disk: the lock holds without the pid in it
                    pass
                return self
            os.close(fd)  # removed by its last holder between our open and our lock: retry
        raise LockedError(f"{self.target}: could not take the lock {self.path}")

    def _same(self, fd: int) -> bool:
        try:
            mine, there = os.fstat(fd), os.lstat(self.path)
        except FileNotFoundError:
            return False
        return (mine.st_dev, mine.st_ino) == (there.st_dev, there.st_ino)

    def release(self) -> None:
        if self._fd is None:
            return
        try:
            if self._same(self._fd):  # never another's file put at the lock's name
                self.path.unlink(missing_ok=True)
        except OSError:
            pass
        os.close(self._fd)
        self._fd = None

    def __enter__(self) -> FileLock:
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()
