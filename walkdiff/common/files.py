"""Writing outputs safely: atomically (no half-written file under a final name), a command's outputs all or
none (`output_set`), one writer at a time (a lock per output), no temporary files left behind by a writer
that was killed, and a write that fails (a full disk, a folder not writable) said with the file and why."""

from __future__ import annotations

import contextlib
import contextvars
import fcntl
import json
import math
import os
import re
import sys
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO

# `.NAME.PID.RANDOM.tmp`: the PID tells a dead writer's leftovers from a live writer's work in progress.
_TEMPORARY = re.compile(r"^\.(?P<name>.+)\.(?P<pid>\d+)\.[^.]+\.tmp$")


def temporary_file(path: str | Path) -> tuple[int, Path]:
    """An open (fd, path) temporary beside `path`, named so that `clean_temporaries` knows its writer."""
    path = Path(path)
    fd, temp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.{os.getpid()}.", suffix=".tmp")
    return fd, Path(temp)


def process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by another user
        return True
    return True


def clean_temporaries(folder: str | Path, name: str | None = None) -> list[Path]:
    """Remove temporary files whose writer has died: of output `name` in `folder`, or anywhere under it.

    Every command runs this when it starts writing, so a killed run's leftovers go with the next run.
    """
    removed = []
    folder = Path(folder)
    if not folder.is_dir():
        return removed
    for entry in folder.glob(".*.tmp") if name is not None else folder.rglob(".*.tmp"):
        match = _TEMPORARY.match(entry.name)
        if match is None or (name is not None and match["name"] != name) or process_alive(int(match["pid"])):
            continue
        with contextlib.suppress(FileNotFoundError):
            entry.unlink()
            removed.append(entry)
    if removed:
        print(
            f"walkdiff: removed {len(removed)} temporary file(s) left in {folder} by a writer that was "
            "stopped: " + ", ".join(p.name for p in removed[:3]),
            file=sys.stderr,
        )
    return removed


def os_reason(error: OSError) -> str:
    """Why a file operation failed, as a message says it: 'no space left on device', 'permission denied'."""
    text = error.strerror or str(error) or type(error).__name__
    return text[:1].lower() + text[1:]


def write_error(path: str | Path, error: OSError):
    """The WalkdiffError of a failed write: the file and the cause."""
    from walkdiff.common.errors import WalkdiffError

    return WalkdiffError(f"cannot write ({os_reason(error)})", path=path)


def write_atomic(path: str | Path, save: Callable[[IO[bytes]], None]) -> Path:
    """Let `save` write into a temporary file in the target folder, then rename it onto `path`; inside an
    `output_set`, the rename waits for the set to be complete. A failed write is a WalkdiffError naming
    `path` and the cause, and leaves no temporary behind."""
    path = Path(path)
    staging = _STAGING.get()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, temp = temporary_file(path)
    except OSError as error:
        raise write_error(path, error) from None
    try:
        with os.fdopen(fd, "wb") as f:
            save(f)
        os.chmod(temp, 0o644)  # mkstemp creates 0600; outputs are meant to be shared
        if staging is None:
            os.replace(temp, path)
        else:
            staging.add(path, temp)
    except BaseException as error:
        Path(temp).unlink(missing_ok=True)
        if isinstance(error, OSError):
            raise write_error(path, error) from None
        raise
    return path


class Outputs:
    """The files of one command, each complete under a temporary name beside its final one until the
    command has written them all (`output_set`)."""

    def __init__(self) -> None:
        self.staged: dict[Path, Path] = {}  # final path -> complete temporary

    def add(self, path: Path, temp: Path) -> None:
        earlier = self.staged.pop(path, None)
        if earlier is not None:  # written twice in one run: the later one counts
            earlier.unlink(missing_ok=True)
        self.staged[path] = temp

    def commit(self) -> None:
        """Give every file written so far its final name."""
        while self.staged:
            path, temp = next(iter(self.staged.items()))
            try:
                os.replace(temp, path)
            except OSError as error:
                raise write_error(path, error) from None
            del self.staged[path]

    def discard(self) -> None:
        for temp in self.staged.values():
            temp.unlink(missing_ok=True)
        self.staged.clear()


_STAGING: contextvars.ContextVar[Outputs | None] = contextvars.ContextVar("walkdiff_outputs", default=None)


def missing_folders(folder: Path) -> list[Path]:
    """`folder` and those of its parents that do not exist yet, deepest first."""
    folder = Path(folder).absolute()
    return [p for p in (folder, *folder.parents) if not p.exists()]


def remove_empty(folders: list[Path]) -> None:
    """Remove the folders this run created (deepest first) where they are empty; keep any with files."""
    for folder in folders:
        try:
            folder.rmdir()
        except FileNotFoundError:
            continue
        except OSError:  # not empty: it holds outputs, or another's files
            return


@contextlib.contextmanager
def output_set(folder: str | Path) -> Iterator[Outputs]:
    """Write a command's outputs all or none: every file written atomically inside (`write_atomic`) gets
    its final name only once the block ends without error, so a run that fails (bad input midway, a full
    disk, an interrupt) or is killed leaves no set without its manifest and replaces no earlier output.
    The output `folder`, and parents of it, that this run created are removed if left empty. Inside
    another set, it joins that one: the outer set names the files."""
    active = _STAGING.get()
    if active is not None:
        yield active
        return
    created = missing_folders(Path(folder))
    outputs = Outputs()
    token = _STAGING.set(outputs)
    try:
        yield outputs
        outputs.commit()
    finally:
        _STAGING.reset(token)
        outputs.discard()
        remove_empty(created)


def link_atomic(link: str | Path, target: str | Path) -> Path:
    """Make `link` a relative symlink to `target`, replacing an earlier link in one step.

    Readers of `link` see the old target or the new one, never a missing file. The temporary link is
    named like every temporary here, so a writer killed between the two steps leaves nothing for good.
    """
    from walkdiff.common.errors import WalkdiffError

    link = Path(link)
    if link.is_dir() and not link.is_symlink():
        raise WalkdiffError("a folder of that name is in the way; expected a link to a file", path=link)
    relative = os.path.relpath(Path(target).absolute(), link.parent.absolute())
    temp = link.parent / f".{link.name}.{os.getpid()}.{os.urandom(4).hex()}.tmp"
    os.symlink(relative, temp)
    try:
        os.replace(temp, link)
    except BaseException:
        temp.unlink(missing_ok=True)
        raise
    return link


@contextlib.contextmanager
def output_lock(path: str | Path, command: str) -> Iterator[Path]:
    """Hold the lock of an output (a folder or a file) while a command writes it.

    The lock is `.NAME.lock` beside the output, so nothing is created before the command has checked
    its inputs. A second writer is refused with the holder's PID and command. It is an flock, which the
    system releases when its holder exits or is killed, so a crash never leaves an output locked; its
    file is removed on release. Once the lock is held, temporary files of writers that died are removed.
    """
    from walkdiff.common.errors import WalkdiffError

    path = Path(path).resolve()
    created = missing_folders(path.parent)  # removed again if the command leaves them empty
    lock = path.parent / f".{path.name}.lock"
    while True:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as error:
            remove_empty(created)
            raise write_error(path, error) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 200).decode("utf-8", "replace").strip()
            os.close(fd)
            pid, _, other = holder.partition(" ")
            raise WalkdiffError(
                f"another walkdiff process (PID {pid or '?'}, `walkdiff {other or '?'}`) is writing this "
                "output; wait for it to finish or choose another output",
                path=path,
            ) from None
        # The previous holder may have removed the file between our open and our lock: lock the new one.
        try:
            same = os.fstat(fd).st_ino == os.stat(lock).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    try:
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()} {command}\n".encode())
        clean_temporaries(path.parent, path.name)
        if path.is_dir():
            clean_temporaries(path)
        yield path
    finally:
        with contextlib.suppress(FileNotFoundError):
            lock.unlink()
        os.close(fd)  # releases the flock
        remove_empty(created)


def check_free(paths: list[Path], overwrite: bool, option: str = "--overwrite") -> None:
    """Refuse to replace existing outputs unless `overwrite`: a WalkdiffError listing them and naming the
    `option` that allows it (the command's flag, or the Python argument)."""
    from walkdiff.common.errors import WalkdiffError

    taken = [str(p) for p in paths if Path(p).exists()]
    if taken and not overwrite:
        more = f" and {len(taken) - 3} more" if len(taken) > 3 else ""
        raise WalkdiffError(f"would overwrite {', '.join(taken[:3])}{more}; pass {option} to replace them")


def output_folder(path: str | Path, option: str = "--out") -> Path:
    """`path` as an output folder, or a WalkdiffError when a file of that name is in the way."""
    from walkdiff.common.errors import WalkdiffError

    path = Path(path)
    if path.exists() and not path.is_dir():
        raise WalkdiffError(
            f"{option}: a file of that name exists; expected a folder for the outputs", path=path
        )
    return path


def write_text(path: str | Path, text: str) -> Path:
    return write_atomic(path, lambda f: f.write(text.encode("utf-8")))


def strict_json(data):
    """`data` with every non-finite float as null: JSON has no NaN or Infinity, strict readers refuse them."""
    if isinstance(data, float):
        return data if math.isfinite(data) else None
    if isinstance(data, dict):
        return {k: strict_json(v) for k, v in data.items()}
    if isinstance(data, list | tuple):
        return [strict_json(v) for v in data]
    return data


def write_json(path: str | Path, data) -> Path:
    """Strict JSON (non-finite numbers become null), written atomically."""
    return write_text(
        path, json.dumps(strict_json(data), indent=2, ensure_ascii=False, allow_nan=False) + "\n"
    )


def read_utf8(path: Path, what: str) -> str:
    """A text file's contents (a UTF-8 byte-order mark dropped), or a WalkdiffError naming `what`."""
    from walkdiff.common.errors import WalkdiffError

    try:
        return Path(path).read_bytes().decode("utf-8-sig")
    except OSError as e:
        raise WalkdiffError(f"cannot read {what} ({e.strerror})", path=path) from None
    except UnicodeDecodeError:
        raise WalkdiffError(f"{what} is not UTF-8 text", path=path) from None


def read_config(path: str | Path, what: str) -> dict:
    """A YAML or JSON mapping from a file, or a WalkdiffError naming the file and what was expected."""
    from omegaconf import OmegaConf

    from walkdiff.common.errors import WalkdiffError

    path = Path(path)
    if not path.is_file():
        raise WalkdiffError(f"{what}: file not found", path=path)
    try:
        data = OmegaConf.to_container(OmegaConf.load(path))
    except Exception as error:  # omegaconf raises yaml's errors, with the line in the message
        raise WalkdiffError(f"{what}: not a YAML/JSON mapping ({error})", path=path) from None
    if not isinstance(data, dict):
        raise WalkdiffError(f"{what}: expected a mapping of fields, got {type(data).__name__}", path=path)
    return data
