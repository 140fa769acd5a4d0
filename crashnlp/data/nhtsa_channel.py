"""NHTSA channel export reader: the per-channel files of the NHTSA database, vNNNNNtsv.CCC.

Each file is one channel (curve CCC of test NNNNN): two tab-separated columns, time [s] and
value, no header, CRLF line ends, time from before impact. The files carry no unit and no test
values: a channel gives its `unit`, the problem (or `crashnlp init --mass --speed`) the mass and
speed. `file` is one channel file of the test, or the folder holding one test's channel files;
a channel's `curves` are the numbers CCC of the files it reads there (averaged; summed for a
force), and a channel without `curves` reads `file` itself.
"""

from __future__ import annotations

from pathlib import Path

from crashnlp.data.channels import Channel, DataError, TestData, check_samples, of_key, si_factor, where
from crashnlp.data.csv_reader import Table
from crashnlp.data.nhtsa_ev5 import combine
from crashnlp.problem.schema import CHANNEL_FILE, ChannelSpec, DataSpec


def channel_files(path: Path) -> tuple[str, dict[int, Path]]:
    """The test number NNNNN `path` names (one of its files, or a folder of one test's files),
    and its channel files by curve number."""
    folder = path if path.is_dir() else path.parent
    named = CHANNEL_FILE.fullmatch(path.name)
    if not path.is_dir() and named is None:
        raise DataError(f"{path}: not an NHTSA channel file (named vNNNNNtsv.CCC)")
    found = [(m.group(1), int(m.group(2)), p) for p in sorted(folder.iterdir()) if (m := CHANNEL_FILE.fullmatch(p.name))]
    tests = sorted({test for test, _, _ in found})
    if named is None and len(tests) != 1:
        what = f"channel files of tests {', '.join(tests)}" if tests else "no NHTSA channel files (vNNNNNtsv.CCC)"
        raise DataError(f"{path}: holds {what}; name one of the test's files")
    test = named.group(1) if named is not None else tests[0]
    return test, {number: p for t, number, p in found if t == test}


def test_channel_files(path: Path) -> list[Path]:
    """Every channel file of the test `path` names (`channel_files`): those its channels may read."""
    return sorted(channel_files(path)[1].values())


def _numbers(path: Path, name: str, ch: ChannelSpec) -> list[int]:
    """The curve numbers a channel reads: its `curves`, else the number of `file`."""
    if isinstance(ch.curves, tuple) and ch.curves:
        return list(ch.curves)
    named = CHANNEL_FILE.fullmatch(path.name)
    if ch.curves is None and named is not None:
        return [int(named.group(2))]
    raise DataError(f"{where(path, name)}: give `curves`, the numbers CCC of the channel files vNNNNNtsv.CCC it reads")


def read_channel_files(spec: DataSpec) -> TestData:
    """Channels from the channel files `ChannelSpec.curves` (averaged when several, summed for a
    force), in SI from the channel's `unit`; combined files must share sample interval and time
    range. No meta: the files carry none."""
    _, files = channel_files(spec.file)
    channels: dict[str, Channel] = {}
    for name, ch in spec.channels.items():
        if ch.derive is not None:
            continue
        with of_key(f"channels.{name}"):
            if ch.unit is None:
                raise DataError(f"{where(spec.file, name)}: no unit (an NHTSA channel file carries none: give `unit`, e.g. g)")
            read = []
            for number in _numbers(spec.file, name, ch):
                file = files.get(number)
                if file is None:
                    raise DataError(
                        f"{where(spec.file, name, f'curve {number}')}: no channel file of the test numbered {number:03d}"
                    )
                table = Table.read(file)
                at = where(file, name)
                time, values = table.values(0, name), table.values(1, name) * si_factor(ch.unit, name, at)
                check_samples(time, values, at)
                read.append((file, time, values))
            channels[name] = combine(read, name)
    return TestData(channels, {})
