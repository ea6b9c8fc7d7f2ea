"""Blob stores for scan uploads and fit results, addressed by relative keys.

Keys look like ``<tenant>/scans/<scan>/scan.ply`` and ``<tenant>/fits/<fit>/result.glb``. Two
backends (``BODYSPACE_BLOB_BACKEND``):

- ``folder`` (default): files under ``BODYSPACE_BLOB_DIR``. Writes go to a temp file in the store,
  are fsync'ed, then renamed (``os.replace``): a reader sees nothing or the whole file. In
  distributed mode every API and worker machine mounts the same folder (NFS, SMB, a cloud file
  share) at that path; rename within a file system is atomic on POSIX and on NFS.
- ``database``: chunks in the ``blob_data`` table of the service database (PostgreSQL in
  distributed mode), written in one transaction. Workers then need nothing shared but the
  database and the broker.

Both stage uploads and results in a local temp file first (:meth:`temp_file`), then
:meth:`commit_file` moves the finished file in.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Protocol

from sqlalchemy import delete, func, select

from service.settings import Settings

CHUNK = 4 * 1024 * 1024


class BlobStore(Protocol):
    """What the service and the workers need from a blob store."""

    def temp_file(self, suffix: str = "") -> Path:
        """A new empty local scratch file (moved in by :meth:`commit_file`)."""

    def commit_file(self, tmp: Path, key: str) -> None:
        """Store the finished file ``tmp`` as ``key`` atomically; ``tmp`` is consumed."""

    def local_path(self, key: str) -> Path | None:
        """The blob's own file when the backend has one (served directly), else None."""

    def local_copy(self, key: str) -> contextlib.AbstractContextManager[Path]:
        """A readable local file with the blob's bytes, for the duration of the context."""

    def iter_chunks(self, key: str) -> Iterator[bytes]:
        """The blob's bytes in chunks (raises FileNotFoundError if absent)."""

    def size(self, key: str) -> int | None:
        """Size in bytes, or None if absent."""

    def delete_prefix(self, prefix: str) -> None:
        """Remove every blob under ``prefix/``."""


class FolderBlobStore:
    """Files under one root folder."""

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

    def temp_file(self, suffix: str = "") -> Path:
        fd, name = tempfile.mkstemp(dir=self.tmp, suffix=suffix)
        os.close(fd)
        return Path(name)

    def commit_file(self, tmp: Path, key: str) -> None:
        dst = self.path(key)
        dst.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, dst)

    def local_path(self, key: str) -> Path | None:
        return self.path(key)

    @contextlib.contextmanager
    def local_copy(self, key: str) -> Iterator[Path]:
        p = self.path(key)
        if not p.is_file():
            raise FileNotFoundError(f"blob {key} is missing")
        yield p

    def iter_chunks(self, key: str) -> Iterator[bytes]:
        with open(self.path(key), "rb") as f:
            while b := f.read(CHUNK):
                yield b

    def size(self, key: str) -> int | None:
        p = self.path(key)
        return p.stat().st_size if p.is_file() else None

    def delete_prefix(self, prefix: str) -> None:
        shutil.rmtree(self.path(prefix), ignore_errors=True)


class DatabaseBlobStore:
    """Chunks in the ``blob_data`` table of the service database; scratch files in ``tmp_dir``."""

    def __init__(self, settings: Settings, tmp_dir: str | os.PathLike) -> None:
        self.settings = settings
        self.tmp = Path(tmp_dir)
        self.tmp.mkdir(parents=True, exist_ok=True)

    def temp_file(self, suffix: str = "") -> Path:
        fd, name = tempfile.mkstemp(dir=self.tmp, suffix=suffix)
        os.close(fd)
        return Path(name)

    def commit_file(self, tmp: Path, key: str) -> None:
        from service.db import session_scope
        from service.models import BlobData

        with session_scope(self.settings) as s, open(tmp, "rb") as f:
            s.execute(delete(BlobData).where(BlobData.key == key))
            seq = 0
            while True:
                b = f.read(CHUNK)
                if not b and seq > 0:
                    break
                s.add(BlobData(key=key, seq=seq, data=b))
                s.flush()
                s.expunge_all()
                seq += 1
                if not b:
                    break
        tmp.unlink(missing_ok=True)

    def local_path(self, key: str) -> Path | None:
        return None

    @contextlib.contextmanager
    def local_copy(self, key: str) -> Iterator[Path]:
        tmp = self.temp_file(Path(key).suffix)
        try:
            with open(tmp, "wb") as f:
                for b in self.iter_chunks(key):
                    f.write(b)
            yield tmp
        finally:
            tmp.unlink(missing_ok=True)

    def _seqs(self, key: str) -> list[int]:
        from service.db import session_scope
        from service.models import BlobData

        with session_scope(self.settings) as s:
            return list(
                s.scalars(select(BlobData.seq).where(BlobData.key == key).order_by(BlobData.seq))
            )

    def iter_chunks(self, key: str) -> Iterator[bytes]:
        from service.db import session_scope
        from service.models import BlobData

        seqs = self._seqs(key)
        if not seqs:
            raise FileNotFoundError(f"blob {key} is missing")
        for seq in seqs:  # one chunk in memory at a time
            with session_scope(self.settings) as s:
                yield s.get_one(BlobData, (key, seq)).data

    def size(self, key: str) -> int | None:
        from service.db import session_scope
        from service.models import BlobData

        with session_scope(self.settings) as s:
            n, total = s.execute(
                select(func.count(), func.sum(func.length(BlobData.data))).where(
                    BlobData.key == key
                )
            ).one()
        return None if not n else int(total or 0)

    def delete_prefix(self, prefix: str) -> None:
        from service.db import session_scope
        from service.models import BlobData

        under = BlobData.key.startswith(prefix.rstrip("/") + "/", autoescape=True)
        with session_scope(self.settings) as s:
            s.execute(delete(BlobData).where(under))


def make_store(settings: Settings) -> BlobStore:
    """The configured blob store."""
    if settings.blob_backend == "database":
        return DatabaseBlobStore(settings, settings.data_dir / "tmp")
    return FolderBlobStore(settings.resolved_blob_dir)


def sha256_file(path: str | os.PathLike, chunk: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while b := f.read(chunk):
            h.update(b)
    return h.hexdigest()
