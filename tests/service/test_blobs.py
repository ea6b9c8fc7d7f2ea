"""Both blob stores: atomic commit, chunked round trip, size, prefix deletion."""

from __future__ import annotations

import os

import pytest

from service.blobs import DatabaseBlobStore, FolderBlobStore, make_store
from service.db import migrate
from service.settings import Settings


@pytest.fixture(params=["folder", "database"])
def store(request, tmp_path):
    settings = Settings(data_dir=tmp_path, database_url=None, blob_backend=request.param)
    migrate(settings)
    return make_store(settings)


def _put(store, key: str, data: bytes) -> None:
    tmp = store.temp_file(".bin")
    tmp.write_bytes(data)
    store.commit_file(tmp, key)
    assert not tmp.exists()


def test_round_trip_of_a_multi_chunk_blob(store):
    data = os.urandom(9 * 1024 * 1024 + 17)  # three 4 MB chunks
    _put(store, "t/scans/s_1/scan.ply", data)
    assert store.size("t/scans/s_1/scan.ply") == len(data)
    assert b"".join(store.iter_chunks("t/scans/s_1/scan.ply")) == data
    with store.local_copy("t/scans/s_1/scan.ply") as p:
        assert p.read_bytes() == data
    _put(store, "t/scans/s_1/scan.ply", b"v2")  # replacing is atomic too
    assert b"".join(store.iter_chunks("t/scans/s_1/scan.ply")) == b"v2"


def test_empty_blob_and_missing_blob(store):
    _put(store, "t/fits/f_1/report.json", b"")
    assert store.size("t/fits/f_1/report.json") == 0
    assert store.size("t/fits/nope/report.json") is None
    with pytest.raises(FileNotFoundError):
        list(store.iter_chunks("t/fits/nope/report.json"))


def test_delete_prefix_removes_only_that_folder(store):
    for key in ["t/fits/f_1/a.glb", "t/fits/f_1/b.ply", "t/fits/f_10/a.glb", "t/fits/fx1/a.glb"]:
        _put(store, key, b"x")
    store.delete_prefix("t/fits/f_1")
    assert store.size("t/fits/f_1/a.glb") is None and store.size("t/fits/f_1/b.ply") is None
    assert store.size("t/fits/f_10/a.glb") == 1  # a sibling with a longer id survives
    assert store.size("t/fits/fx1/a.glb") == 1  # '_' is not a wildcard


def test_backends(tmp_path):
    assert isinstance(make_store(Settings(data_dir=tmp_path)), FolderBlobStore)
    s = Settings(data_dir=tmp_path, blob_backend="database")
    assert isinstance(make_store(s), DatabaseBlobStore)
    with pytest.raises(ValueError):
        FolderBlobStore(tmp_path).path("../escape")
