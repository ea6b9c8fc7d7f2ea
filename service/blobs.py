"""Blob store: scan uploads and fit results as files under one root folder.

Keys are relative paths (``<tenant>/scans/<scan>/scan.ply``, ``<tenant>/fits/<fit>/result.glb``).
Writes are atomic: data go to a temporary file in the target folder, are fsync'ed, then renamed
(``os.replace``), so a reader sees either nothing or the whole file.

Distributed mode: every API and worker machine mounts the same folder (NFS, SMB, a cloud file
share, …) at the path given by ``BODYSPACE_BLOB_DIR``. Rename within one folder is atomic on
POSIX file systems and on NFS, which is all this store relies on.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import tempfile
from collections.abc import Iterable
from pathlib import Path


class BlobStore:
    """A folder of immutable files addressed by relative keys."""

    def __init__(self, root: str | os.PathLike) -> None:
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)
        self.tmp = self.root / ".tmp"
        self.tmp.mkdir(exist_ok=True)

    def path(self, key: str) -> Path:
        """The file of ``key`` (keys may not escape the root)."""
        p = (self.root / key).resolve()
        if self.root.resolve() not in p.parents:
            raise ValueError(f"invalid blob key {key!r}")
        return p

    def exists(self, key: str) -> bool:
        return self.path(key).is_file()

    def temp_file(self, suffix: str = "") -> Path:
        """A new empty file in the store's temp folder (same file system: renames are atomic)."""
        fd, name = tempfile.mkstemp(dir=self.tmp, suffix=suffix)
        os.close(fd)
        return Path(name)

    def commit_file(self, tmp: Path, key: str) -> None:
        """Move a finished temp file into place as ``key`` (fsync + atomic rename)."""
        dst = self.path(key)
        dst.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, dst)

    def put_bytes(self, key: str, data: bytes) -> tuple[int, str]:
        """Write ``data`` atomically; returns (size, sha256)."""
        return self.put_chunks(key, [data])

    def put_chunks(self, key: str, chunks: Iterable[bytes]) -> tuple[int, str]:
        """Write the chunks atomically as ``key``; returns (size, sha256)."""
        dst = self.path(key)
        dst.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{dst.name}.", suffix=".tmp", dir=dst.parent)
        h = hashlib.sha256()
        size = 0
        try:
            with os.fdopen(fd, "wb") as f:
                for c in chunks:
                    f.write(c)
                    h.update(c)
                    size += len(c)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, dst)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise
        return size, h.hexdigest()

    def delete(self, key: str) -> None:
        with contextlib.suppress(FileNotFoundError):
            self.path(key).unlink()

    def delete_prefix(self, prefix: str) -> None:
        """Remove a folder of blobs (e.g. everything of one scan)."""
        p = self.path(prefix)
        shutil.rmtree(p, ignore_errors=True)


def sha256_file(path: str | os.PathLike, chunk: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while b := f.read(chunk):
            h.update(b)
    return h.hexdigest()
