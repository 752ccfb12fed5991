"""Write an output file whole or not at all."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any, BinaryIO


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike[str]) -> Iterator[BinaryIO]:
    """A binary file to write ``path`` through: a temporary file in the same folder that,
    when the block ends without error, is flushed, synced and renamed over ``path``
    (``os.replace``). Readers see the old file or the whole new one, never a part; on an
    error the temporary file is removed and ``path`` is left as it was.
    """
    target = Path(path)
    fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def write_json(path: str | os.PathLike[str], value: Any) -> Path:
    """Write ``value`` to ``path`` as indented JSON and a newline, atomically
    (``atomic_output``); NaN and infinities are refused (strict JSON). Returns the path."""
    text = json.dumps(value, indent=2, allow_nan=False)
    with atomic_output(path) as f:
        f.write(text.encode() + b"\n")
    return Path(path)


@contextlib.contextmanager
def staged_files(out_dir: str | os.PathLike[str], names: Iterable[str]) -> Iterator[Path]:
    """A temporary folder inside ``out_dir`` (created if missing) to write the files
    ``names`` into; when the block ends without error each is moved over its namesake
    in ``out_dir`` (``os.replace``, one rename each). On an error nothing in ``out_dir``
    is replaced. The temporary folder is removed either way."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".staging-", dir=out))
    try:
        yield staging
        for name in names:
            os.replace(staging / name, out / name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
