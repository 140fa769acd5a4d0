"""CasADi Functions compiled to C once and cached on disk.

The virtual machine costs a few nanoseconds per instruction; the same
instructions compiled run several times faster. Compiling takes a second or
two, so each library is kept under the cache folder (CRASHNLP_CACHE, default
~/.cache/crashnlp), named by a hash of the Function as CasADi serializes it, CasADi's
version, the compiler and its flags: the same function is compiled once per machine, whatever
the process. Without a C
compiler the Function itself is returned, so results never depend on it.

A compile runs in a process group of its own (crashnlp.numerics.compile_job), waited for here,
and ends with the process that started it, on exit as on a signal, leaving no
half-written library (it is renamed into place once whole).

A library is loaded only once it is found whole (`load_cached`, every loader's way in): its compile
writes the sha256 of it and of its companions (the list of its Functions' names) beside it
(crashnlp.numerics.compile_job.record_of); a library without a record (compiled before records
were kept) is whole where its ELF file holds every part its headers place (`whole_elf`). A library
that is not whole, or that fails to load with nothing to vouch for it, is removed with its
companions and compiled again as a missing one is; one its record vouches for that still fails to
load (a cache on a noexec mount) is left, and the process stays in the VM without compiling it
again. A cache that cannot be written (read-only) keeps what it holds.

Once per machine, not once per process: each library has a lock file beside it (LIBRARY.lock;
`locked`, `try_lock`: flock), held exclusively by its compile from before its source is written
until the library is renamed into place, so that the workers of a study that all need the same
function start one compile, not one each. A process that finds the lock held waits for it, as it
would wait for its own compile (the other compile is as far along or further, and a wait takes no
core from it), then loads the library. The kernel releases a flock when its holder dies, however
it dies, so a crashed compile never holds a lock.

Whether a library is being compiled is seen by taking its lock shared for an instant
(`compiling`): lookers never see each other, and a compile that tries the lock meanwhile
(`try_lock`) waits the look out instead of giving up; it gives up at once only on a compile.

A compile killed by SIGKILL removes nothing: its source (LIBRARY.c) and partial library (or
record) stay in the cache. The next compile of any library (`start`) removes them: its own library's, under the
lock it holds, and every other library's whose lock no compile holds, taken shared meanwhile so that
none starts. A running compile's files are never removed.

What a compile may take (`start`): the cache within CRASHNLP_CACHE_MB, the least recently used
libraries and kept files (KEPT: YAML values, stored models, unit conversions, IPOPT's options)
removed first (`used`, `_make_room`); and no more than half the memory available, else it is
not started (`TooLarge`) and the functions stay in CasADi's virtual machine.
"""

from __future__ import annotations

import fcntl
import hashlib
import math
import os
import shutil
import struct
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager, nullcontext, suppress
from functools import cache, partial
from pathlib import Path
from typing import TypeVar

import casadi as ca
import numpy as np

from crashnlp.base.cache import CACHE_ENV, KEPT, cache_dir, used
from crashnlp.base.errors import InputError
from crashnlp.numerics import compile_job

__all__ = [
    "CACHE_ENV",
    "Evaluator",
    "TooLarge",
    "build",
    "cache_dir",
    "cache_limit",
    "compiled",
    "compiler",
    "compiling",
    "intact",
    "load_cached",
    "locked",
    "refused",
    "start",
    "start_behind",
    "try_lock",
    "used",
]

SWITCH_ENV = "CRASHNLP_COMPILE"  # "0": CasADi's virtual machine only; "model": the model's functions, not the NLPs
FLAGS = ("-O2", "-fPIC", "-shared")
TRY_WAIT_S = 0.5  # how long a compile's try waits out lookers: a look holds the lock for microseconds
TRY_POLL_S = 0.001
LIMIT_ENV = "CRASHNLP_CACHE_MB"  # the cache's size (MB) past which a compile first removes the least recently used files
DEFAULT_LIMIT_MB = 2048.0
# gcc's peak memory per byte of CasADi's C, measured at the NLPs' -O1: 99 to 117 for 4 to 14 MB of
# C, 150 and more for 47 MB (docs/design-notes.md, "What a compile takes"); the model's functions,
# compiled at -O2, are kilobytes
MEMORY_PER_SOURCE_BYTE = 160
T = TypeVar("T")
_loaded: dict[str, ca.Function] = {}
_too_large: set[Path] = set()  # the libraries this process did not compile for want of memory (`start`)


def compiler(nlp: bool = False) -> str | None:
    """The C compiler on PATH (CC, else cc or gcc), or None: always with CRASHNLP_COMPILE=0,
    and for an NLP's functions (`nlp`) with CRASHNLP_COMPILE=model too (the tests: every test
    NLP has a shape of its own, and a compile costs more than its solve)."""
    switch = os.environ.get(SWITCH_ENV)
    if switch == "0" or (nlp and switch == "model"):
        return None
    return _on_path(os.environ.get("CC"), os.environ.get("PATH"))


@cache
def _on_path(cc: str | None, path: str | None) -> str | None:
    """The first of CC, cc and gcc on `path` (searched once per process and PATH: a search
    costs half a millisecond, and a solve asks several times)."""
    return next((name for name in (cc, "cc", "gcc") if name and shutil.which(name, path=path)), None)


def compiled(fn: ca.Function, jacobian: bool = False) -> ca.Function:
    """`fn` as a compiled external Function with the same inputs and outputs.

    It has no derivatives, except its Jacobian with `jacobian` (which
    CasADi's integrators ask for when they are built, even when unused)."""
    cc = compiler()
    if cc is None:
        return fn
    # keyed by the Function as CasADi serializes it, not by its C: generating the C only to find
    # its library costs ten times as much (16 ms for the model's right-hand side)
    what = [fn.serialize(), f"jacobian={jacobian}", ca.CasadiMeta.version(), cc, *FLAGS]
    key = hashlib.sha256("\0".join(what).encode()).hexdigest()[:20]
    if key not in _loaded:
        library = cache_dir() / f"{fn.name()}-{key}.so"
        try:
            load = partial(ca.external, fn.name(), str(library))
            external = load_cached(library, load)
            if external is None:
                with locked(library) as lock:  # another process compiling it: its library, once written
                    if not library.exists():
                        build(cc, _source(fn, jacobian), library, lock)
                external = load_cached(library, load)
        except (OSError, RuntimeError, subprocess.CalledProcessError):  # no usable compiler or cache: stay in the VM
            return fn
        _loaded[key] = fn if external is None else external  # once a process, loaded or not
    return _loaded[key]


def load_cached(library: Path, load: Callable[[], T]) -> T | None:
    """What `load` makes of the cached `library` (ca.external, ctypes.CDLL), the library marked `used`;
    None where the cache holds none, or none that loads. A library that is not whole (`intact`: a
    truncated library is mapped whole by the dynamic loader, which dies of SIGBUS where it reads
    past the end), or that fails to load with no record to vouch for it, is removed with its
    companions (`_discard`), so that it is compiled again as a missing one is; one its record vouches
    for is left where it fails to load (the cache's mount, not the library), so that no run compiles
    it again. The caller stays in the VM meanwhile."""
    if not library.exists():
        return None
    vouched = intact(library)
    if vouched is not False:
        try:
            loaded = load()
        except (OSError, RuntimeError):
            if vouched:
                return None
        else:
            used(library)
            return loaded
    _discard(library)
    return None


def intact(library: Path) -> bool | None:
    """Whether `library` and its companions (a library's Functions' names) are what its compile wrote:
    the record beside them (crashnlp.numerics.compile_job.record_of) gives their sha256 now; None
    where it has no record and its ELF file is whole (`whole_elf`: nothing vouches for its content,
    but loading it cannot crash), False where either fails. Hashing the largest library (some MB)
    costs milliseconds, once a process."""
    try:
        kept = compile_job.record_of(library).read_text()
    except FileNotFoundError:
        return None if whole_elf(library) else False
    except (OSError, ValueError):  # a record that is not text
        return False
    try:
        return kept == compile_job.record(library, library)
    except OSError:
        return False


def whole_elf(path: Path) -> bool:
    """Whether `path` is a 64-bit ELF file (a Linux shared library) as long as its headers say: its
    section headers and every segment it loads lie within it. A file cut short fails; a file that
    is no ELF file fails too (the dynamic loader refuses it, so only a record could vouch for it)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(64)
            size = os.fstat(fh.fileno()).st_size
            if len(head) < 64 or head[:4] != b"\x7fELF" or head[4] != 2 or head[5] not in (1, 2):
                return False
            order = "<" if head[5] == 1 else ">"
            phoff, shoff = struct.unpack_from(order + "QQ", head, 0x20)
            phentsize, phnum, shentsize, shnum = struct.unpack_from(order + "HHHH", head, 0x36)
            if shoff + shnum * shentsize > size or phoff + phnum * phentsize > size:
                return False
            fh.seek(phoff)
            table = fh.read(phnum * phentsize)
    except OSError:
        return False
    segments = (struct.unpack_from(order + "IIQQQQ", table, i * phentsize) for i in range(phnum))
    return all(offset + filesz <= size for _, _, offset, _, _, filesz in segments)


def _discard(library: Path) -> None:
    """Remove `library`, its companions and its record (`_files`), unless a compile holds its lock
    (looked at meanwhile, `_looked_at`: that compile writes them afresh), or the cache cannot be
    written (read-only: what it holds stays, and the caller stays in the VM)."""
    with suppress(OSError), _looked_at(library) as free:
        if free:
            _remove(_files(library))


def _files(library: Path) -> list[Path]:
    """`library` and the files kept beside it that go with it: its companions and its record."""
    return [library, *compile_job.companions(library), compile_job.record_of(library)]


def _source(fn: ca.Function, jacobian: bool) -> str:
    """The C of `fn`, and of its Jacobian with `jacobian`."""
    gen = ca.CodeGenerator(f"{fn.name()}.c", {"with_header": False, "casadi_real": "double"})
    gen.add(fn)
    if jacobian:
        gen.add(fn.jacobian())
    return gen.dump()


def try_lock(library: Path) -> int | None:
    """An open descriptor of `library`'s lock file, flocked exclusively for the caller (to compile
    it), or None if a compile holds it. Lookers (`compiling`, `start`'s clean-up) hold it shared for
    an instant: a try that finds only them waits them out (polling, TRY_WAIT_S at most), so that a
    look never stops a compile. The lock is released when every descriptor of it is closed: this
    one and the copy a compile inherits (crashnlp.numerics.compile_job.start), closed by the kernel
    when their processes die, however they die."""
    fd = _lock_file(library)
    deadline = time.monotonic() + TRY_WAIT_S
    try:
        while not _flock(fd, fcntl.LOCK_EX):
            if compiling(library) or time.monotonic() > deadline:
                os.close(fd)
                return None
            time.sleep(TRY_POLL_S)
    except BaseException:
        os.close(fd)
        raise
    return fd


@contextmanager
def locked(library: Path) -> Iterator[int]:
    """`library`'s lock held exclusively for the block, waited for while another holds it; yields its
    descriptor (for `build`). Check inside that the library is still missing, since the holder
    waited for may have written it."""
    fd = _lock_file(library)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield fd
    finally:
        os.close(fd)


def compiling(library: Path) -> bool:
    """Whether a compile holds `library`'s lock now (exclusively)."""
    with _looked_at(library) as free:
        return not free


@contextmanager
def _looked_at(library: Path) -> Iterator[bool]:
    """`library`'s lock held shared for the block if no compile holds it (True), else not held
    (False), without waiting. Shared, a look never makes another look or a compile's try give up
    (`try_lock`)."""
    fd = _lock_file(library)
    try:
        yield _flock(fd, fcntl.LOCK_SH)
    finally:
        os.close(fd)


def _flock(fd: int, operation: int) -> bool:
    """Whether `fd` got the flock `operation` (LOCK_EX or LOCK_SH) without waiting."""
    try:
        fcntl.flock(fd, operation | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    return True


def _lock_file(library: Path) -> int:
    """An open descriptor of LIBRARY.lock beside `library`, made if need be. Lock files stay (empty):
    one removed while held would let a second compile start on a new one."""
    library.parent.mkdir(parents=True, exist_ok=True)
    return os.open(library.with_suffix(".lock"), os.O_RDWR | os.O_CREAT, 0o666)


def build(cc: str, source: str, library: Path, lock: int, flags: tuple[str, ...] = FLAGS) -> None:
    """Compile `source` into `library` and wait, for the holder of its lock `lock` (`start`); a
    signal meanwhile stops the compile."""
    compile = start(cc, source, library, flags, lock)
    try:
        code = compile.wait()
    finally:
        compile_job.stop_compiles([compile])
    if code != 0:
        raise subprocess.CalledProcessError(code, compile.args)


class TooLarge(RuntimeError):
    """A compile not started: it would take more memory than this machine can spare (`start`)."""


def start(
    cc: str, source: str, library: Path, flags: tuple[str, ...], lock: int, what: str = compile_job.NLP, nice: int = 0
) -> subprocess.Popen:
    """Start compiling `source` into `library` (crashnlp.numerics.compile_job), for the holder of its
    lock `lock` (`try_lock`, `locked`), which the compile holds too until it ends. The source is
    written beside the library (LIBRARY.c) and removed by the compile however it ends but by
    SIGKILL; it runs at niceness `nice`, and `what` names it in the line that says it goes on after
    the command. First, what
    compiles killed by SIGKILL left in the cache is removed (`_remove_leftovers`) and the cache is
    brought within its limit (`_make_room`).

    A compile that would take more than half the memory available now (MEMORY_PER_SOURCE_BYTE) is
    not started: one line on stderr says so, and TooLarge is raised (the caller stays in CasADi's
    virtual machine, as without a compiler). Its other half stays the user's: a compile finishes
    after the command, and gcc thrashing in swap would take the machine with it."""
    _affordable(source, library)
    _remove_leftovers(library)
    _make_room(library)
    path = library.with_suffix(".c")
    path.write_text(source)
    return compile_job.start(cc, path, library, flags, cleanup=(path,), lock=lock, what=what, nice=nice)


def start_behind(
    cc: str, library: Path, flags: tuple[str, ...], source: Callable[[], str], what: str = compile_job.NLP, nice: int = 0
) -> None:
    """Start compiling `library` beside this process (`start`), holding its lock: not if a compile
    holds it, or wrote the library meanwhile. `source` makes the C once the lock is held (and
    whatever the library needs beside it)."""
    lock = try_lock(library)
    if lock is None:
        return
    try:
        if not library.exists():
            start(cc, source(), library, flags, lock, what=what, nice=nice)
    finally:
        os.close(lock)  # the compile holds its own copy


def _remove_leftovers(own: Path) -> None:
    """Remove the sources and partial libraries that compiles killed by SIGKILL left in `own`'s
    folder: `own`'s (the caller holds its lock), and those of every other library whose lock no
    compile holds, looked at meanwhile (`_looked_at`) so that none starts. Files without a lock
    file beside their library are not a compile's, and stay."""
    for library, files in _leftovers(own).items():
        if library == own:
            _remove(files)
        elif library.with_suffix(".lock").exists():
            with _looked_at(library) as free:
                if free:
                    _remove(files)


def _leftovers(own: Path) -> dict[Path, list[Path]]:
    """The compiles' sources (LIBRARY.c), partial libraries and partial records
    (crashnlp.numerics.compile_job.partial) in `own`'s folder, by library."""
    found: dict[Path, list[Path]] = {}
    for path in own.parent.iterdir():
        written = path if path.suffix == ".c" else compile_job.partial_of(path)
        if written is not None and written.suffix in (".c", compile_job.RECORD, own.suffix):
            found.setdefault(written.with_suffix(own.suffix), []).append(path)
    return found


def _remove(files: list[Path]) -> None:
    for path in files:
        path.unlink(missing_ok=True)


def cache_limit() -> float:
    """The cache's size limit in bytes: CRASHNLP_CACHE_MB megabytes, DEFAULT_LIMIT_MB where unset."""
    raw = os.environ.get(LIMIT_ENV, "").strip()
    try:
        megabytes = float(raw) if raw else DEFAULT_LIMIT_MB
    except ValueError:
        megabytes = math.nan
    if not megabytes >= 0:
        raise InputError(f"{LIMIT_ENV}={raw}: expected a size in megabytes (a number >= 0)")
    return megabytes * 1e6


def _make_room(adding: Path) -> None:
    """Remove the least recently used (`used`) libraries of `adding`'s folder, each with its
    companions and record (`_files`), and kept files (KEPT: the values of YAML files, stored models,
    the units table, IPOPT's options), until the folder's files take at most `cache_limit()`: not `adding`, nor a library
    whose lock a compile holds (looked at meanwhile, `_looked_at`, so that none starts). A process
    that has a removed library loaded keeps it; the next that needs it compiles it again, as the
    next that needs a removed kept file makes it again."""
    files = {path: path.stat() for path in adding.parent.iterdir() if path.is_file()}
    total, limit = sum(s.st_size for s in files.values()), cache_limit()
    removable = (p for p in files if p != adding and (p.suffix == adding.suffix or _kept(p)))
    for path in sorted(removable, key=lambda p: files[p].st_mtime):
        if total <= limit:
            return
        kept = _kept(path)
        with nullcontext(True) if kept else _looked_at(path) as free:
            if free:
                gone = [path] if kept else _files(path)
                total -= sum(files[p].st_size for p in gone if p in files)
                _remove(gone)


def _kept(path: Path) -> bool:
    """Whether `path` is a kept file (KEPT), removed without a lock."""
    return any(path.match(pattern) for pattern in KEPT)


def refused(library: Path) -> bool:
    """Whether this process found `library` too large to compile (`start`): its source need not be
    generated again."""
    return library in _too_large


def _affordable(source: str, library: Path) -> None:
    """Raise TooLarge, and say so on stderr once a process, where compiling `source` would take more
    than half the memory available now (`start`); nothing where the available memory is not known."""
    if library in _too_large:
        raise TooLarge(library.name)
    available = available_memory()
    need = len(source) * MEMORY_PER_SOURCE_BYTE
    if available is not None and need > available / 2:
        line = (
            f"crashnlp: {library.stem} is not compiled: its {len(source) / 1e6:.0f} MB of C would take gcc about "
            f"{need / 1e9:.1f} GB of memory, of {available / 1e9:.1f} GB available; it runs in CasADi's virtual machine"
        )
        print(line, file=sys.stderr)
        _too_large.add(library)
        raise TooLarge(line)


def available_memory() -> float | None:
    """The memory available to a new process now, in bytes (Linux: /proc/meminfo's MemAvailable;
    elsewhere the free pages), or None where neither is known."""
    with suppress(OSError, ValueError, StopIteration):
        with open("/proc/meminfo") as meminfo:
            return float(next(line for line in meminfo if line.startswith("MemAvailable:")).split()[1]) * 1024
    with suppress(OSError, ValueError, AttributeError):
        return float(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    return None


class Evaluator:
    """Evaluates a Function on numpy arrays through a FunctionBuffer, with no conversion to
    and from CasADi matrices (which costs more than the evaluation for long outputs)."""

    def __init__(self, fn: ca.Function, outputs: tuple[str, ...] | None = None):
        self.fn = fn
        self.buffer, self._evaluate = fn.buffer()
        self.outputs = [fn.index_out(name) for name in outputs] if outputs else list(range(fn.n_out()))

    def __call__(self, **inputs: np.ndarray) -> list[np.ndarray]:
        """Outputs (dense, the Function's shapes) for named inputs; unnamed inputs are zero."""
        held = []
        for name, value in inputs.items():
            i = self.fn.index_in(name)
            a = np.ravel(np.asarray(value, dtype=float), order="F")  # column-major, as CasADi stores
            if a.size != self.fn.nnz_in(i):
                raise ValueError(f"{self.fn.name()}: input {name} has {a.size} values, expected {self.fn.nnz_in(i)}")
            held.append(a)
            self.buffer.set_arg(i, memoryview(a))  # type: ignore[call-arg, arg-type]  # the stub asks a size the binding takes from the buffer
        results = []
        for i in self.outputs:
            r = np.empty(self.fn.size_out(i)[::-1])
            results.append(r)
            self.buffer.set_res(i, memoryview(r.ravel()))  # type: ignore[call-arg, arg-type]  # as set_arg
        self._evaluate()
        if self.buffer.ret() != 0:
            raise RuntimeError(f"{self.fn.name()}: evaluation failed")
        return [r.T for r in results]
