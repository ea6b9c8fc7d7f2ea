"""Marker (landmark) files: CSV ``name,x,y,z`` with a header row, or JSON.

Markers are in the scan's file units and axes; :func:`core.io.prepare.load_scan` maps them to
the canonical frame with the scan's :class:`core.scan.FrameInfo`. Valid names are the template's
landmark names (``core.template.load_template().landmarks``); missing landmarks are simply
absent from the result.
"""

from __future__ import annotations

import json
import math
import os
from collections import Counter
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from core.errors import MarkerError

Source = str | os.PathLike | bytes | bytearray
_ECHO = 60  # characters of user input quoted in a message


def _load_text(source: Source) -> tuple[str, str]:
    """-> (decoded text without BOM, a name for messages)."""
    if isinstance(source, bytes | bytearray):
        raw, what = bytes(source), "marker file"
    else:
        what = str(source)
        try:
            raw = Path(source).read_bytes()
        except OSError as e:
            raise MarkerError(f"cannot read marker file {what}: {e.strerror}", path=what) from None
    enc = "utf-16" if raw[:2] in (b"\xff\xfe", b"\xfe\xff") else "utf-8-sig"
    try:
        text = raw.decode(enc)
    except UnicodeDecodeError:
        raise MarkerError(
            f"{what}: marker file is not UTF-8 text; save it as UTF-8 CSV or JSON"
        ) from None
    return text.lstrip("\ufeff"), what


def _detect(text: str, source: Source, fmt: str | None) -> str:
    if fmt:
        f = fmt.lower().lstrip(".")
        if f not in ("csv", "json"):
            raise MarkerError(f"unknown marker format {fmt!r}; use 'csv' or 'json'")
        return f
    if not isinstance(source, bytes | bytearray):
        ext = Path(source).suffix.lower()
        if ext in (".csv", ".txt"):
            return "csv"
        if ext == ".json":
            return "json"
    return "json" if text.lstrip()[:1] in ("{", "[") else "csv"


def _to_point(vals: Iterable[Any], where: str, what: str) -> np.ndarray:
    vals = list(vals)
    if len(vals) != 3:
        raise MarkerError(
            f"{what}: {where} has {len(vals)} coordinates, expected 3 (x, y, z)", where=where
        )
    out = []
    for v in vals:
        if isinstance(v, bool) or v is None:
            ok = False
        else:
            try:
                f = float(v)
                ok = True
            except (TypeError, ValueError):
                ok = False
        if not ok:
            raise MarkerError(
                f"{what}: {where} has a non-numeric coordinate {_clip(repr(v))}; use plain numbers",
                where=where,
            )
        if not math.isfinite(f):
            raise MarkerError(
                f"{what}: {where} has a non-finite coordinate {_clip(repr(v))}; use finite "
                "numbers, or leave the marker out if it was not measured",
                where=where,
            )
        out.append(f)
    return np.array(out, dtype=np.float64)


def _parse_csv(text: str, what: str) -> list[tuple[str, Any, str]]:
    rows: list[tuple[str, Any, str]] = []
    header_seen = False
    for lineno, line in enumerate(text.splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        sep = "," if "," in s else (";" if ";" in s else None)
        cells = [c.strip().strip('"').strip("'").strip() for c in s.split(sep)]
        if not header_seen:
            header_seen = True
            low = [c.lower() for c in cells]
            if (
                len(low) >= 4
                and low[0] in ("name", "marker", "landmark", "label")
                and low[1:4] == ["x", "y", "z"]
            ):
                continue
            if len(cells) == 4:
                try:
                    [float(c) for c in cells[1:]]
                except ValueError:
                    raise MarkerError(
                        f"{what}: line {lineno} should be the header 'name,x,y,z', "
                        f"got {_clip(s)!r}",
                        line=lineno,
                    ) from None
                # no header row: accept the data row as is
        where = f"line {lineno} ({s[:60]!r})"
        if len(cells) != 4:
            raise MarkerError(
                f"{what}: {where} has {len(cells)} columns, expected 4: name,x,y,z",
                line=lineno,
            )
        rows.append((cells[0], cells[1:], where))
    return rows


def _clip(s: str, n: int = _ECHO) -> str:
    """At most ``n`` characters of user input for a message (``…`` marks a cut)."""
    return s if len(s) <= n else s[: n - 1] + "…"


def _names(names: Iterable[str], n: int = 10) -> str:
    """A bounded list of (clipped) names for a message: the first ``n`` and how many more."""
    names = list(names)
    shown = ", ".join(repr(_clip(x, 40)) for x in names[:n])
    return shown + (f" and {len(names) - n:,} more" if len(names) > n else "")


def _parse_json(text: str, what: str) -> list[tuple[str, Any, str]]:
    def no_dups(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
        obj = dict(pairs)
        if len(obj) != len(pairs):  # linear: count names only when some repeat
            dup = sorted(k for k, c in Counter(k for k, _ in pairs).items() if c > 1)
            raise MarkerError(
                f"{what}: duplicate marker name(s) {_names(dup)}; give each marker once",
                duplicates=[_clip(d, 40) for d in dup[:10]],
            )
        return obj

    try:
        obj = json.loads(text, object_pairs_hook=no_dups)
    except json.JSONDecodeError as e:
        raise MarkerError(
            f"{what}: invalid JSON at line {e.lineno}, column {e.colno}: {e.msg}", line=e.lineno
        ) from None
    except RecursionError:
        raise MarkerError(
            f"{what}: JSON nested too deeply; markers are "
            '{"name": [x, y, z], ...} or a list of {"name", "x", "y", "z"} objects'
        ) from None
    rows: list[tuple[str, Any, str]] = []
    if isinstance(obj, dict) and isinstance(obj.get("markers"), list | dict):
        obj = obj["markers"]
    if isinstance(obj, dict):
        for name, val in obj.items():
            where = f"marker {_clip(name)!r}"
            if not isinstance(val, list | tuple):
                raise MarkerError(
                    f"{what}: {where} must be a list [x, y, z], got {_clip(json.dumps(val))}",
                    where=where,
                )
            rows.append((str(name), val, where))
    elif isinstance(obj, list):
        for i, item in enumerate(obj):
            where = f"entry {i}"
            if not isinstance(item, dict) or "name" not in item:
                raise MarkerError(
                    f"{what}: {where} must be an object with keys name, x, y, z", where=where
                )
            where = f"entry {i} ({_clip(str(item['name']))!r})"
            if all(k in item for k in "xyz"):
                pt = [item["x"], item["y"], item["z"]]
            elif isinstance(item.get("position"), list):
                pt = item["position"]
            else:
                raise MarkerError(f"{what}: {where} lacks x, y, z", where=where)
            rows.append((str(item["name"]), pt, where))
    else:
        raise MarkerError(
            f'{what}: JSON markers must be an object {{"name": [x, y, z], ...}} or a list of '
            '{"name", "x", "y", "z"} objects'
        )
    return rows


def read_markers(
    source: Source,
    fmt: str | None = None,
    *,
    valid_names: Iterable[str],
    name: str | None = None,
) -> dict[str, np.ndarray]:
    """Read a marker file.

    Parameters
    ----------
    source : path or bytes
        CSV ``name,x,y,z`` with a header row (whitespace, a UTF-8 BOM, CRLF line ends and ``#``
        comment lines are tolerated) or JSON ``{"name": [x, y, z], ...}`` / a list of
        ``{"name", "x", "y", "z"}`` objects.
    fmt : {"csv", "json"}, optional
        By default from the extension, else from the content.
    valid_names : iterable of str
        The allowed names (the template's landmark names).
    name : str, optional
        What messages call the file (e.g. an upload's filename); default its path.

    Returns
    -------
    dict
        name -> (3,) float64 position in the file's units and axes.

    Raises
    ------
    MarkerError
        Unknown or duplicate names, wrong column counts, non-numeric or non-finite values.
    """
    text, what = _load_text(source)
    what = what if name is None else name
    if not text.strip():
        raise MarkerError(f"{what}: marker file is empty")
    f = _detect(text, source, fmt)
    rows = _parse_csv(text, what) if f == "csv" else _parse_json(text, what)
    valid = set(valid_names)
    seen: dict[str, str] = {}
    unknown: list[str] = []
    for label, _, where in rows:  # names first (cheap), then the coordinates
        if label in seen:
            raise MarkerError(
                f"{what}: duplicate marker {_clip(label)!r} at {where}; give each marker once",
                name=_clip(label),
            )
        if label not in valid:
            unknown.append(label)
        seen[label] = where
    if unknown:
        raise MarkerError(
            f"{what}: unknown marker name(s) {_names(unknown)}; valid names are: "
            f"{', '.join(sorted(valid))}",
            unknown=[_clip(u, 40) for u in unknown[:10]],
            n_unknown=len(unknown),
            valid=sorted(valid),
        )
    return {label: _to_point(vals, where, what) for label, vals, where in rows}


def write_markers_csv(path: str | os.PathLike, markers: Mapping[str, Any]) -> None:
    """Write markers as CSV ``name,x,y,z`` with a header row (atomic write).

    Parameters
    ----------
    path : output file.
    markers : name -> (3,) position.
    """
    from core.io.writers import atomic_write

    lines = ["name,x,y,z"]
    for name, p in markers.items():
        if "," in name or "\n" in name:
            raise MarkerError(f"marker name {name!r} must not contain commas or newlines")
        x, y, z = (float(v) for v in np.asarray(p, dtype=np.float64).reshape(3))
        lines.append(f"{name},{x!r},{y!r},{z!r}")
    atomic_write(path, ("\n".join(lines) + "\n").encode("utf-8"))
