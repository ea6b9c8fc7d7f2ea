"""Streaming multipart parsing: file parts go straight to temp files in the blob store.

Nothing is held whole in memory, and each part has its own byte limit, checked while the body
streams in: an oversized upload is answered ``413`` without storing it.
"""

from __future__ import annotations

import contextlib
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from python_multipart.multipart import MultipartParser, parse_options_header
from starlette.requests import Request

from service.blobs import BlobStore
from service.errors import ApiError, clip

FIELD_LIMIT = 64 * 1024
MAX_PARTS = 16  # parts (files and text fields) in one body
DRAIN_LIMIT = 64 * 1024 * 1024  # read (and discard) at most this much past a limit, then answer


@dataclass
class UploadedFile:
    """A file part written to a temp file of the blob store."""

    field: str
    filename: str
    content_type: str
    path: Path
    size: int = 0


@dataclass
class Form:
    files: dict[str, UploadedFile] = field(default_factory=dict)
    fields: dict[str, str] = field(default_factory=dict)

    def cleanup(self) -> None:
        """Remove temp files not moved into the store."""
        for f in self.files.values():
            with contextlib.suppress(FileNotFoundError):
                f.path.unlink()


class _TooLargeError(Exception):
    def __init__(self, name: str, limit: int) -> None:
        self.name, self.limit = name, limit


class _RefusedError(Exception):
    def __init__(self, error: ApiError) -> None:
        self.error = error


_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")


def safe_filename(name: str) -> str:
    """An upload's filename as stored and shown: its last path component, without control
    characters (NUL, newlines, ...), at most 200 characters (the extension kept); ``upload``
    when nothing is left."""
    base = _CONTROL.sub("", name).replace("\\", "/").rsplit("/", 1)[-1].strip()
    if base in ("", ".", ".."):
        return "upload"
    if len(base) > 200:
        stem, dot, ext = base.rpartition(".")
        base = stem[:190] + dot + ext[:9] if dot and len(ext) <= 9 else base[:200]
    return base


async def _drain(request: Request, budget: int) -> None:
    read = 0
    async for chunk in request.stream():
        read += len(chunk)
        if read > budget:
            break


async def parse_multipart(request: Request, store: BlobStore, file_limits: dict[str, int]) -> Form:
    """Parse a ``multipart/form-data`` body; ``file_limits`` maps file field -> max bytes.

    Limits hold while the body streams in, whether or not ``Content-Length`` is sent: each part's
    bytes, the body's total bytes (the file limits + 16 text fields), at most :data:`MAX_PARTS`
    parts, and file parts only under the names of ``file_limits``.

    Raises :class:`ApiError` ``unsupported_media_type`` (not multipart), ``upload_too_large``
    (a part or the body over its limit), ``too_many_parts``, ``validation_error`` (a file part
    under another name) or ``bad_request`` (a malformed body).
    """
    ctype, params = parse_options_header(request.headers.get("content-type", ""))
    if ctype != b"multipart/form-data" or b"boundary" not in params:
        raise ApiError(
            "unsupported_media_type",
            f"expected multipart/form-data, got {ctype.decode('latin-1') or 'no content type'!r}",
        )
    total_limit = sum(file_limits.values()) + 16 * FIELD_LIMIT
    declared = request.headers.get("content-length")
    if declared and declared.isdigit() and int(declared) > total_limit:
        if int(declared) <= total_limit + DRAIN_LIMIT:
            await _drain(request, DRAIN_LIMIT + total_limit)
        raise ApiError(
            "upload_too_large",
            f"the upload is {int(declared):,} bytes; the limit is {total_limit:,} bytes",
            limit_bytes=total_limit,
            size_bytes=int(declared),
        )

    form = Form()
    state: dict = {"headers": {}, "hname": b"", "hval": b"", "file": None, "buf": None}
    out: dict[str, IO[bytes] | None] = {"fh": None}

    def on_part_begin() -> None:
        state["headers"] = {}
        state["parts"] = state.get("parts", 0) + 1
        if state["parts"] > MAX_PARTS:
            raise _RefusedError(
                ApiError(
                    "too_many_parts",
                    f"the body has more than {MAX_PARTS} parts; send the scan, the markers "
                    "and the text fields once each",
                    limit=MAX_PARTS,
                )
            )

    def on_header_field(data: bytes, start: int, end: int) -> None:
        state["hname"] += data[start:end]

    def on_header_value(data: bytes, start: int, end: int) -> None:
        state["hval"] += data[start:end]

    def on_header_end() -> None:
        state["headers"][state["hname"].decode("latin-1").lower()] = state["hval"]
        state["hname"], state["hval"] = b"", b""

    def on_headers_finished() -> None:
        _, disp = parse_options_header(state["headers"].get("content-disposition", b""))
        name = disp.get(b"name", b"").decode("utf-8", "replace")
        filename = disp.get(b"filename")
        state["name"] = name
        if filename is not None and name not in file_limits:
            raise _RefusedError(
                ApiError(
                    "validation_error",
                    f"unexpected file part {clip(name)!r}; files go in "
                    f"{', '.join(repr(k) for k in file_limits)}",
                    field=clip(name),
                )
            )
        if filename is not None:
            fname = safe_filename(filename.decode("utf-8", "replace"))
            suffix = Path(fname).suffix.lower()[:8]
            up = UploadedFile(
                name,
                fname,
                state["headers"].get("content-type", b"").decode("latin-1"),
                store.temp_file(suffix),
            )
            if name in form.files:  # a repeated field: keep the last
                form.files[name].path.unlink(missing_ok=True)
            form.files[name] = up
            state["file"] = up
            out["fh"] = open(up.path, "wb")  # noqa: SIM115 (closed in on_part_end)
            state["buf"] = None
        else:
            state["file"] = None
            state["buf"] = bytearray()

    def on_part_data(data: bytes, start: int, end: int) -> None:
        up: UploadedFile | None = state["file"]
        n = end - start
        if up is not None:
            limit = file_limits.get(up.field, FIELD_LIMIT)
            up.size += n
            if up.size > limit:
                raise _TooLargeError(up.field, limit)
            out["fh"].write(data[start:end])  # type: ignore[union-attr]
        else:
            buf: bytearray = state["buf"]
            if len(buf) + n > FIELD_LIMIT:
                raise _TooLargeError(state["name"], FIELD_LIMIT)
            buf += data[start:end]

    def on_part_end() -> None:
        if out["fh"] is not None:
            out["fh"].close()
            out["fh"] = None
        elif state["buf"] is not None:
            form.fields[state["name"]] = state["buf"].decode("utf-8", "replace")

    parser = MultipartParser(
        params[b"boundary"],
        {
            "on_part_begin": on_part_begin,
            "on_part_data": on_part_data,
            "on_part_end": on_part_end,
            "on_header_field": on_header_field,
            "on_header_value": on_header_value,
            "on_header_end": on_header_end,
            "on_headers_finished": on_headers_finished,
        },
    )
    total = 0
    try:
        async for chunk in request.stream():
            total += len(chunk)
            if total > total_limit:
                raise _TooLargeError("body", total_limit)
            parser.write(chunk)
        parser.finalize()
    except _RefusedError as e:
        if out["fh"] is not None:
            out["fh"].close()
        form.cleanup()
        await _drain(request, DRAIN_LIMIT)
        raise e.error from None
    except _TooLargeError as e:
        if out["fh"] is not None:
            out["fh"].close()
        form.cleanup()
        await _drain(request, DRAIN_LIMIT)
        what = "the body" if e.name == "body" else f"the {clip(e.name)!r} part"
        raise ApiError(
            "upload_too_large",
            f"{what} is larger than its limit of {e.limit:,} bytes",
            field=clip(e.name),
            limit_bytes=e.limit,
        ) from None
    except ApiError:
        form.cleanup()
        raise
    except Exception as e:
        if out["fh"] is not None:
            out["fh"].close()
        form.cleanup()
        raise ApiError("bad_request", f"malformed multipart body: {clip(str(e))}") from None
    return form
