"""C compiles in process groups of their own, which end with the process that started them.

`start` runs one, `stop_compiles` ends those this process started (at the end of a command
or of a study worker). A compile is `python -m crashnlp.compile_job [--watch] LIBRARY SOURCE
[CLEANUP...] -- CC FLAGS...`: it compiles SOURCE into a temporary file beside LIBRARY and
renames that in place when the compiler succeeds, so that no reader sees half a library.
With `--watch` it reads its standard input until end of file, which comes when its starter
closes the pipe or dies, however it dies; the whole group (compiler driver, cc1, as) is then
stopped. Whatever the ending, the temporary file and the CLEANUP files (the source, which is
a background compile's lock) are removed. Without `--watch` (`keep`, or
CRASHNLP_KEEP_COMPILING=1) the compile outlives its starter, for the next run.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
from contextlib import suppress
from pathlib import Path

KEEP_ENV = "CRASHNLP_KEEP_COMPILING"  # "1": a background compile outlives the command (for the next run)
STOP_WAIT_S = 10.0  # how long a stopped compile may take to remove its files before its group is killed
_compiles: list[subprocess.Popen] = []  # the compiles this process started and has not stopped


def start(
    cc: str, source: Path, library: Path, flags: tuple[str, ...], cleanup: tuple[Path, ...] = (), keep: bool | None = None
) -> subprocess.Popen:
    """Start compiling the file `source` into `library` (crashnlp.compile_job: through a temporary
    name, `cleanup` removed at the end). It ends with this process unless `keep` (default: KEEP_ENV)."""
    keep = os.environ.get(KEEP_ENV) == "1" if keep is None else keep
    job = [sys.executable, "-m", "crashnlp.compile_job", *([] if keep else ["--watch"])]
    compile = subprocess.Popen(
        [*job, str(library), str(source), *map(str, cleanup), "--", cc, *flags],
        stdin=subprocess.DEVNULL if keep else subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    if not keep:
        _compiles.append(compile)
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


def _stop_group_at_end_of_input() -> None:
    while os.read(0, 4096):  # the raw descriptor: a daemon thread must hold no lock of sys.stdin at exit
        pass
    os.killpg(0, signal.SIGTERM)  # this process only notes it (its handler); the compiler's processes end


def main(argv: list[str]) -> int:
    watch = argv[:1] == ["--watch"]
    files, command = argv[watch : argv.index("--")], argv[argv.index("--") + 1 :]
    library, source, *cleanup = (Path(f) for f in files)
    partial = library.with_name(f".{library.name}.{os.getpid()}.tmp")
    signal.signal(signal.SIGTERM, lambda signum, frame: None)  # a handler, not SIG_IGN: the compiler gets the default
    try:
        compiler = subprocess.Popen([*command, str(source), "-o", str(partial), "-lm"], stdin=subprocess.DEVNULL)
        if watch:
            threading.Thread(target=_stop_group_at_end_of_input, daemon=True).start()
        code = compiler.wait()
        if code == 0:
            os.replace(partial, library)
        return 0 if code == 0 else 1
    finally:
        for path in (partial, *cleanup):
            path.unlink(missing_ok=True)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
