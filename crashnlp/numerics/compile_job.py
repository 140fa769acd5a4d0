"""C compiles in process groups of their own: stopped with a command that fails, is interrupted
or is killed; finished after one that succeeds, in the background at the lowest priority.

`start` runs one; at the end of a command that succeeded `release_compiles` lets those still
running finish for the next run (unless CRASHNLP_KEEP_COMPILING=0) and says so on the console,
`stop_compiles` ends them (any other ending, a study worker's end, KEEP_ENV=0). A Python script or
notebook that used crashnlp as a library (crashnlp.api) gets the same at its interpreter's exit
(`_at_exit`): its compiles finish for its next run, with the same line, unless Ctrl-C ended it.

A compile is `python -I .../compile_job.py NICE LIBRARY SOURCE [CLEANUP...] -- CC FLAGS...`: at
niceness NICE (0, or BACKGROUND_NICE for one that no process waits for: it gives way to the
command from its start), it compiles SOURCE into a temporary file beside LIBRARY and renames that
in place when the compiler succeeds, so that no reader sees half a library. The library's record
(`record_of`: the sha256 of it and of its COMPANIONS) is put in place before it, so that a reader
that finds the library finds the record that vouches for it (crashnlp.numerics.compiled.load_cached).
It reads its standard input until end of file,
which comes when its starter closes the pipe or dies, however it dies; the whole group (compiler
driver, cc1, as) is then stopped, unless the starter wrote RELEASE first: then the group goes on
at nice 19, so that it takes only cores nothing else wants. Any compile ends itself after
TIME_LIMIT_S. Whatever the ending but SIGKILL, the temporary file (`partial`) and the CLEANUP
files (the source) are removed; after SIGKILL the next compile removes them
(crashnlp.numerics.compiled.start).

A starter that holds the library's lock (crashnlp.numerics.compiled.try_lock) passes it to the
compile (`lock`): the compile inherits the locked descriptor and holds the lock until it ends,
after the renaming, however it ends (the kernel closes a dead process's descriptors). Its
compiler does not inherit it.
"""

from __future__ import annotations

import atexit
import hashlib
import os
import re
import signal
import subprocess
import sys
import threading
from contextlib import suppress
from pathlib import Path

KEEP_ENV = "CRASHNLP_KEEP_COMPILING"  # "0": a background compile ends with the command (default: it finishes, at nice 19)
RELEASE = b"release\n"  # what a starter writes to a watched compile that is to finish without it
BACKGROUND_NICE = 19
TIME_LIMIT_S = 900.0  # a compile still running after this ends itself
STOP_WAIT_S = 10.0  # how long a stopped compile may take to remove its files before its group is killed
# this file, run isolated (-I: no current folder or PYTHON* variables on its path; it needs only the
# standard library): `-m crashnlp.numerics.compile_job` ran the crashnlp of the folder a command was started in
COMPANIONS = (".names",)  # files a starter writes beside a library before its compile (crashnlp.optimize.oracle)
RECORD = ".sha256"  # a library's record, beside it: what its compile wrote (`record`)
NLP = "this problem's NLP"  # what a compile is, unless its starter says (`start`)
JOB = (sys.executable, "-I", str(Path(__file__).resolve()))
_compiles: list[subprocess.Popen] = []  # the compiles this process started and has not stopped
_what: dict[int, str] = {}  # what each compile (process id) is compiling, for the line of `release_compiles`


def start(
    cc: str,
    source: Path,
    library: Path,
    flags: tuple[str, ...],
    cleanup: tuple[Path, ...] = (),
    lock: int | None = None,
    what: str = NLP,
    nice: int = 0,
) -> subprocess.Popen:
    """Start compiling the file `source` into `library` (crashnlp.numerics.compile_job: through a temporary
    name, `cleanup` removed at the end) at niceness `nice`, holding the locked descriptor `lock` while it
    runs. It ends with this process unless released (`release_compiles`, whose line names it `what`)."""
    compile = subprocess.Popen(
        [*JOB, str(nice), str(library), str(source), *map(str, cleanup), "--", cc, *flags],
        stdin=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
        pass_fds=() if lock is None else (lock,),
    )
    _compiles.append(compile)
    _what[compile.pid] = what
    return compile


def stop_compiles(compiles: list[subprocess.Popen] | None = None) -> None:
    """Stop `compiles` (default: every one this process started) and wait until their files are
    removed: the end of a command. One that does not end within STOP_WAIT_S is killed with its group."""
    for compile in list(_compiles if compiles is None else compiles):
        if compile.stdin is not None:
            compile.stdin.close()  # its end of input: it stops its group and removes its files
        try:
            compile.wait(timeout=STOP_WAIT_S)
        except subprocess.TimeoutExpired:
            with suppress(ProcessLookupError):
                os.killpg(compile.pid, signal.SIGKILL)
            compile.wait()
        if compile in _compiles:
            _compiles.remove(compile)


def release_compiles() -> list[int]:
    """At the end of a command: the compiles this process started and that still run finish in
    the background at nice BACKGROUND_NICE, for the next run, and one line says so; with
    KEEP_ENV=0 they are stopped instead. Returns the released compiles' process ids."""
    if os.environ.get(KEEP_ENV) == "0":
        stop_compiles()
        return []
    released = []
    for compile in list(_compiles):
        if compile.poll() is None and compile.stdin is not None:
            with suppress(BrokenPipeError):  # it ended meanwhile
                compile.stdin.write(RELEASE)
                compile.stdin.close()
                released.append(compile.pid)
                _compiles.remove(compile)
    stop_compiles()  # those that ended: waited for
    if released:
        what = " and ".join(dict.fromkeys(_what.pop(pid, NLP) for pid in released))
        print(
            f"crashnlp: compiling {what} in the background for the next run (pid {', '.join(map(str, released))}, "
            f"nice {BACKGROUND_NICE}, ends within {TIME_LIMIT_S / 60:.0f} min); {KEEP_ENV}=0 turns this off",
            file=sys.stderr,
        )
    return released


def _at_exit() -> None:
    """The exit of an interpreter that started compiles and did not end them itself (the command
    line does, crashnlp.cli.main; a script or notebook using crashnlp.api does not): they finish
    for the next run, as after a command that succeeded, and the line says so (KEEP_ENV=0 stops
    them); an interpreter whose last uncaught exception was Ctrl-C's KeyboardInterrupt stops them,
    as the command line does. Killed by a signal, an interpreter runs no exit handler: its
    compiles see their input end and stop."""
    if isinstance(getattr(sys, "last_value", None), KeyboardInterrupt):
        stop_compiles()
    else:
        release_compiles()


atexit.register(_at_exit)


def partial(library: Path, pid: int) -> Path:
    """Where the compile with process id `pid` writes `library` until it is whole (hidden, beside it)."""
    return library.with_name(f".{library.name}.{pid}.tmp")


def partial_of(path: Path) -> Path | None:
    """The library that `path` is a partial of (`partial`), or None."""
    match = re.fullmatch(r"\.(.+)\.[0-9]+\.tmp", path.name)
    return path.with_name(match[1]) if match else None


def record_of(library: Path) -> Path:
    """Where the record of `library` is kept (`record`)."""
    return library.with_suffix(RECORD)


def companions(library: Path) -> list[Path]:
    """The files a starter may write beside `library` (COMPANIONS), there or not."""
    return [library.with_suffix(suffix) for suffix in COMPANIONS]


def sha256_of(path: Path) -> str:
    """The sha256 of a file's contents (hex). Here, not in crashnlp.base: a compile runs this module
    as a script (`python -I`), which imports nothing of crashnlp's."""
    with open(path, "rb") as fh:
        return hashlib.file_digest(fh, "sha256").hexdigest()


def record(library: Path, built: Path) -> str:
    """The record of `library`, whose content is the file `built`: the sha256 of it and of each of its
    companions there now, a line each in sha256sum's format (`sha256sum -c LIBRARY.sha256` in the
    cache folder checks them)."""
    files = [(library.name, built), *((path.name, path) for path in companions(library) if path.exists())]
    return "".join(f"{sha256_of(path)}  {name}\n" for name, path in files)


def _put_in_place(built: Path, library: Path) -> None:
    """Rename the whole library `built` to `library`, its record (`record`) written first through a
    temporary file (`partial`) renamed in place: whoever sees the library sees its record."""
    written = partial(record_of(library), os.getpid())
    try:
        written.write_text(record(library, built))
        os.replace(written, record_of(library))
    finally:
        written.unlink(missing_ok=True)
    os.replace(built, library)


def _watch_starter() -> None:
    """Stop the group at the end of input, unless the starter released it first: then lower the
    group's priority (the compiler's processes, and those the driver starts later) and go on."""
    received = b""
    while chunk := os.read(0, 4096):  # the raw descriptor: a daemon thread must hold no lock of sys.stdin at exit
        received += chunk
    if received == RELEASE:
        os.setpriority(os.PRIO_PGRP, 0, BACKGROUND_NICE)
        return
    _stop_group(signal.SIGTERM, None)


_stopping = [False]  # this process has sent its group SIGTERM (a plain flag: set from a signal handler too)


def _stop_group(signum: int, frame: object) -> None:
    """SIGTERM to this process (`kill PID`, the pid the starter's line names) stops its whole group,
    the compiler's processes too, once: the group's own SIGTERM (`_watch_starter`, the time limit)
    reaches this process as well, and is not sent again."""
    if not _stopping[0]:
        _stopping[0] = True
        os.killpg(0, signal.SIGTERM)


def main(argv: list[str]) -> int:
    files, command = argv[1 : argv.index("--")], argv[argv.index("--") + 1 :]
    if int(argv[0]) > os.getpriority(os.PRIO_PROCESS, 0):  # never below the starter's (not allowed)
        os.setpriority(os.PRIO_PROCESS, 0, int(argv[0]))
    library, source, *cleanup = (Path(f) for f in files)
    temporary = partial(library, os.getpid())
    signal.signal(signal.SIGTERM, _stop_group)  # a handler, not SIG_IGN: the compiler gets the default
    try:
        compiler = subprocess.Popen([*command, str(source), "-o", str(temporary), "-lm"], stdin=subprocess.DEVNULL)
        if _stopping[0]:  # stopped while the compiler started: it was not in the group yet
            compiler.terminate()
        threading.Thread(target=_watch_starter, daemon=True).start()
        try:
            code = compiler.wait(timeout=TIME_LIMIT_S)
        except subprocess.TimeoutExpired:
            _stop_group(signal.SIGTERM, None)
            code = compiler.wait()
        if code == 0:
            _put_in_place(temporary, library)
        return 0 if code == 0 else 1
    finally:
        for path in (temporary, *cleanup):
            path.unlink(missing_ok=True)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
