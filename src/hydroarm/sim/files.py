"""Files that are whole or untouched: what the runner, the output folders and the executor write.

A run's trajectory, a study's JSON and a worker's result are written to a temporary file
beside the target and renamed over it (:func:`atomic_file`), so an interrupt never leaves half
a file.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, Any


@contextlib.contextmanager
def atomic_file(path: str | Path) -> Iterator[IO[bytes]]:
    """A binary handle on a temporary file beside ``path`` that replaces ``path`` when the
    block ends without an error (else it is removed): ``path`` is whole or untouched."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with tmp.open("wb") as handle:
            yield handle
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def atomic_write(path: str | Path, data: str | bytes) -> None:
    """Write ``data`` (text as UTF-8) to ``path`` atomically (:func:`atomic_file`)."""
    with atomic_file(path) as handle:
        handle.write(data.encode() if isinstance(data, str) else data)


def file_bytes(write: Callable[[Path], Any], name: str = "file") -> bytes:
    """The bytes ``write(path)`` puts in a file (a worker's file, for the driver to write)."""
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / name
        write(path)
        return path.read_bytes()
