"""The ``bodyspace`` command line.

Subcommands are registered by small ``register(subparsers)`` functions. The built-in ones (``fit``,
``demo``) live here; others (``serve``, ``worker``, ``keys``, …) are added by an optional module
``service/commands.py`` exposing ``register(subparsers)`` — it is imported when present (see
:data:`PLUGIN_MODULES`). A registered parser sets ``func`` (``handler(args) -> int``) with
``parser.set_defaults(func=...)``; heavy imports belong inside the handler so that ``bodyspace
--help`` stays fast and one command's optional dependency cannot break another.

Exit codes: 0 success; 1 unexpected internal error (rerun with ``--debug`` for the traceback);
2 bad input or usage (domain errors from ``core``, missing files, unsupported output formats);
130 interrupted.
"""

from __future__ import annotations

import argparse
import importlib
import json
import math
import sys
import time
import traceback
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from core.io.frame import UNITS_OPTIONS
from core.serialize import json_ready

PROG = "bodyspace"
OUT_FORMATS = (".ply", ".obj", ".glb")
UP_CHOICES = ("auto", "+x", "-x", "+y", "-y", "+z", "-z")
EXAMPLES_DIR = Path(__file__).resolve().parent.parent / "core" / "assets" / "examples"


# Modules exposing ``register(subparsers)``, imported when present.
PLUGIN_MODULES = ("service.commands", "worker.cli")


class CliError(Exception):
    """A user-facing problem: printed as one ``bodyspace: error: …`` line, exit code 2."""


Registrar = Callable[[argparse._SubParsersAction], None]


# --------------------------------------------------------------------------- small helpers


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("bodyspace")
    except Exception:  # not installed (e.g. run from a source tree)
        return "0+unknown"


def _check_out_path(path: Path, formats: Sequence[str] = OUT_FORMATS, what: str = "--out") -> Path:
    """Fail early (before a long fit) on an unsupported extension or an unwritable folder."""
    ext = path.suffix.lower()
    if ext not in formats:
        raise CliError(
            f"{what} {str(path)!r}: unsupported extension {ext or '(none)'!r}; "
            f"use {', '.join(formats)}"
        )
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise CliError(f"{what} {str(path)!r}: folder {str(folder)!r} does not exist")
    if path.is_dir():
        raise CliError(f"{what} {str(path)!r} is a directory")
    import os

    if not os.access(folder, os.W_OK | os.X_OK):
        raise CliError(f"{what} {str(path)!r}: folder {str(folder)!r} is not writable")
    return path


def _check_in_path(path: Path, what: str) -> Path:
    if not path.exists():
        raise CliError(f"{what} not found: {str(path)!r}")
    if path.is_dir():
        raise CliError(f"{what} {str(path)!r} is a directory, not a file")
    return path


class ProgressBar:
    """A dependency-free text progress bar on stderr, fed by ``core.registration`` Progress.

    On a terminal one line is redrawn in place; otherwise (logs, pipes) one line is printed per
    stage so that logs stay short.
    """

    def __init__(self, stream: TextIO | None = None, width: int = 24, enabled: bool = True):
        self.stream = stream or sys.stderr
        self.width = width
        self.enabled = enabled
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._last_stage = -1
        self._drawn = False

    def start(self, message: str = "fit: aligning markers and the body prior ...") -> None:
        """Say that work has begun (the first progress report comes after initialisation)."""
        if self.enabled:
            self.stream.write(message + ("" if self.tty else "\n"))
            self.stream.flush()
            self._drawn = self.tty

    def __call__(self, p: Any) -> None:
        if not self.enabled:
            return None
        frac = float(p.fraction)
        filled = round(frac * self.width)
        bar = "#" * filled + "-" * (self.width - filled)
        total = p.energy.get("total", float("nan"))
        line = (
            f"fit [{bar}] stage {p.stage + 1}/{p.n_stages} ({p.resolution}) "
            f"iter {p.iteration + 1:2d}  E={total:.4g}  step={p.max_step_m * 1000:.2f} mm  "
            f"{p.elapsed_s:5.1f} s"
        )
        if self.tty:
            self.stream.write("\r\x1b[K" + line)
            self._drawn = True
        elif p.stage != self._last_stage:
            self.stream.write(line + "\n")
        self._last_stage = p.stage
        self.stream.flush()
        return None

    def close(self, ok: bool = True) -> None:
        """End the bar: keep the last line after success, erase it after a failure."""
        if self.enabled and self.tty and self._drawn:
            done = f"\r\x1b[Kfit [{'#' * self.width}] done\n"
            self.stream.write(done if ok else "\r\x1b[K")
            self.stream.flush()
        self._drawn = False


# --------------------------------------------------------------------------- fitting


def _fit_markerless(scan: Any, **options: Any) -> Any:
    """Fit without markers: shape-space start from an automatic alignment, then refinement."""
    from core.matching.markerless import fit_markerless

    if not options.pop("shape_prior", True):
        raise CliError(
            "fitting without markers needs the body prior: use --schedule default or fast, "
            "or give a marker file with --markers"
        )
    return fit_markerless(scan, **options)


def run_fit(
    scan_path: Path,
    markers_path: Path | None,
    *,
    units: str = "auto",
    up: str = "auto",
    fast: bool = False,
    quiet: bool = False,
    schedule: str = "default",
) -> tuple[Any, Any, dict[str, Any]]:
    """Load a scan (and markers), fit it and time each step.

    Returns
    -------
    (scan, FitResult, info)
        ``info`` holds the inputs, the frame and timings for the report.
    """
    from core.io import load_scan
    from core.matching.marker_checks import fit_checking_markers
    from core.registration.schedule import preset

    t0 = time.perf_counter()
    scan, markers = load_scan(scan_path, units=units, up=up, markers_path=markers_path)
    if scan.colors is not None and Path(scan_path).suffix.lower() in (".obj", ".glb", ".zip"):
        from core.io import read_mesh
        from core.transfer.texture import textured_surface

        # a textured scan: its surface as read, for the texture at full resolution
        scan.textured = textured_surface(read_mesh(scan_path), scan.frame)
    t_load = time.perf_counter() - t0
    schedule = "fast" if fast else schedule
    options = preset(schedule)
    bar = ProgressBar(enabled=not quiet)
    t1 = time.perf_counter()
    bar.start()
    ok = False
    try:
        if markers is None:
            result = _fit_markerless(scan, callback=bar, **options)
        else:
            result = fit_checking_markers(scan, markers, callback=bar, **options)
        from core.transfer.colour import colour_fit

        colour_fit(result, scan)
        ok = True
    finally:
        bar.close(ok)
    t_fit = time.perf_counter() - t1
    frame = scan.frame
    info: dict[str, Any] = {
        "bodyspace_version": _version(),
        "inputs": {
            "scan": str(scan_path),
            "markers": None if markers_path is None else str(markers_path),
            "units_option": units,
            "up_option": up,
        },
        "frame": {
            "units": None if frame is None else frame.units,
            "up": None if frame is None else frame.up,
            "detected": None if frame is None else bool(frame.detected),
            "scale_to_m": None if frame is None else float(frame.scale),
        },
        "schedule": schedule,
        "timing_s": {"load": t_load, "fit": t_fit},
    }
    return scan, result, info


def write_outputs(result: Any, outs: Sequence[Path], report_path: Path | None, info: dict) -> dict:
    """Write the fitted body to each of ``outs`` and (optionally) the JSON report."""
    from core.io import write_mesh
    from core.io.writers import atomic_write

    t0 = time.perf_counter()
    colors = result.colors
    texture = None
    for out in outs:
        if colors is not None and out.suffix.lower() in (".glb", ".obj"):
            # baked on the template UV layout: a textured GLB, or OBJ + MTL + PNG
            from core.transfer.texture import fit_texture, textured_glb, write_textured_obj

            if texture is None:
                texture = fit_texture(colors, result.texture)
            if out.suffix.lower() == ".glb":
                textured_glb(out, result.vertices, texture)
            else:
                write_textured_obj(out, result.vertices, texture)
            continue
        write_mesh(out, result.vertices, result.faces, colors=colors)
    info["outputs"] = [str(p) for p in outs]
    info["timing_s"]["write"] = time.perf_counter() - t0
    info["timing_s"]["total"] = sum(v for v in info["timing_s"].values())
    report = {**result.report.to_dict(), **info}
    if report_path is not None:
        text = json.dumps(json_ready(report), indent=2, allow_nan=False)
        atomic_write(report_path, (text + "\n").encode("utf-8"))
    return report


def _mm(x: float) -> str:
    return "n/a" if x is None or not math.isfinite(x) else f"{x * 1000:.1f} mm"


def summary_lines(result: Any, info: dict) -> list[str]:
    """A short human summary of a fit (printed to stdout)."""
    r = result.report
    t = info["timing_s"]
    fr = info["frame"]
    how = "detected" if fr.get("detected") else "given"
    lines = [
        f"fitted {Path(info['inputs']['scan']).name} in {t['total']:.1f} s "
        f"(load {t['load']:.1f} s, fit {t['fit']:.1f} s, write {t['write']:.1f} s; "
        f"{info['schedule']} schedule)",
        f"  scan: {r.scan_vertices:,} points, {r.scan_faces:,} triangles"
        + (
            f" (kept; {sum(r.removed.values()):,} removed as not the body)"
            if any(r.removed.values())
            else ""
        )
        + f"; units {fr['units']}, up {fr['up']} ({how})",
        f"  scan->fit distance: mean {_mm(r.scan_to_fit_mean_m)}, p95 {_mm(r.scan_to_fit_p95_m)}; "
        f"template vertices without scan data: {r.no_data_fraction * 100:.1f} %",
    ]
    dropped = r.markers_dropped
    m = f"  markers: {len(r.markers_used)} used, {len(dropped)} dropped"
    if dropped:
        m += " (" + ", ".join(dropped[:8]) + (", ..." if len(dropped) > 8 else "") + ")"
    lines.append(m)
    lines.extend(f"  warning: {w}" for w in r.warnings if not w.startswith("quality:"))
    lines.append("  wrote " + ", ".join(info.get("outputs", [])))
    return lines


# --------------------------------------------------------------------------- `fit`


def _cmd_fit(args: argparse.Namespace) -> int:
    scan_path = _check_in_path(Path(args.scan), "scan file")
    markers_path = None
    if args.markers is not None:
        markers_path = _check_in_path(Path(args.markers), "marker file")
    elif args.fast or args.schedule != "paper":
        pass  # markerless: the body prior finds the body
    else:
        raise CliError(
            "fitting without markers needs the body prior: use --schedule default or fast, "
            "or give a marker file with --markers"
        )
    out = _check_out_path(Path(args.out))
    report_path = None
    if args.report is not None:
        report_path = _check_out_path(Path(args.report), (".json",), "--report")
    _, result, info = run_fit(
        scan_path,
        markers_path,
        units=args.units,
        up=args.up,
        fast=args.fast,
        quiet=args.quiet,
        schedule=args.schedule,
    )
    write_outputs(result, [out], report_path, info)
    if report_path is not None:
        info["outputs"].append(str(report_path))
    if not args.quiet:
        print("\n".join(summary_lines(result, info)))
    return quality_exit(result)


EXIT_QUALITY_FAILED = 3


def quality_exit(result: Any) -> int:
    """Print the fit's quality verdict (one line on stderr); the exit code it means.

    ``failed`` (a body part lost, collapsed or misplaced) exits with 3 — the fitted body and the
    report are still written, for inspection; ``good`` and ``suspect`` exit with 0.
    """
    q = result.report.quality
    if q is None:
        return 0
    print(f"{PROG}: {q.summary()}", file=sys.stderr)
    return EXIT_QUALITY_FAILED if q.quality == "failed" else 0


def register_fit(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "fit",
        help="fit the template body to a scan with markers",
        description="Fit the template body to a raw scan guided by anatomical markers and "
        "write the fitted body (template vertex order, metres, +Y up).",
    )
    p.add_argument("scan", metavar="SCAN", help="scan file: .ply, .obj, .stl, .npz or .xyz")
    p.add_argument(
        "--markers",
        metavar="MARKERS",
        help="marker file, CSV name,x,y,z (header row) or JSON {name: [x, y, z]}, "
        "in the scan's units and axes",
    )
    p.add_argument("--out", required=True, metavar="FIT", help="fitted body: .ply, .obj or .glb")
    p.add_argument("--report", metavar="REPORT.json", help="write the JSON fit report here")
    p.add_argument("--units", choices=UNITS_OPTIONS, default="auto", help="scan units")
    p.add_argument("--up", choices=UP_CHOICES, default="auto", help="scan up axis")
    p.add_argument(
        "--schedule",
        choices=("default", "fast", "paper"),
        default="default",
        help="default: body prior + full-resolution refinement; fast: a short preview; "
        "paper: Allen et al. 2003's four-stage schedule from the bare template",
    )
    p.add_argument("--fast", action="store_true", help="same as --schedule fast")
    p.add_argument("--quiet", action="store_true", help="no progress bar and no summary")
    p.set_defaults(func=_cmd_fit)


# --------------------------------------------------------------------------- `demo`


def truth_error(result: Any, scan: Any, truth_file: np.ndarray) -> dict[str, float]:
    """Per-vertex distance (metres) between the fit and the truth body (both template order)."""
    truth = np.asarray(truth_file, dtype=np.float64)
    if scan.frame is not None:
        truth = scan.frame.to_canonical(truth)
    d = np.linalg.norm(result.vertices - truth, axis=1)
    return {
        "mean_m": float(d.mean()),
        "p95_m": float(np.percentile(d, 95)),
        "max_m": float(d.max()),
    }


def _cmd_demo(args: argparse.Namespace) -> int:
    ex = EXAMPLES_DIR
    scan_path = _check_in_path(ex / "example_scan.ply", "bundled example scan")
    markers_path = _check_in_path(ex / "example_markers.csv", "bundled example markers")
    truth_path = ex / "example_truth.npz"
    out_dir = Path(args.out_dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise CliError(f"cannot create --out-dir {str(out_dir)!r}: {e.strerror}") from None
    outs = [_check_out_path(out_dir / "fit.glb"), _check_out_path(out_dir / "fit.ply")]
    report_path = out_dir / "report.json"
    if not args.quiet:
        print(f"demo: fitting the bundled example {scan_path.name} with {markers_path.name}")
    scan, result, info = run_fit(scan_path, markers_path, fast=args.fast, quiet=args.quiet)
    if truth_path.exists():
        with np.load(truth_path) as z:
            info["truth_error_m"] = truth_error(result, scan, z["vertices"])
    write_outputs(result, outs, report_path, info)
    info["outputs"].append(str(report_path))
    if not args.quiet:
        lines = summary_lines(result, info)
        te = info.get("truth_error_m")
        if te is not None:
            lines.insert(
                -1,
                f"  fit->truth correspondence error: mean {_mm(te['mean_m'])}, "
                f"p95 {_mm(te['p95_m'])}, max {_mm(te['max_m'])}",
            )
        print("\n".join(lines))
    return 0


def register_demo(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "demo",
        help="fit the bundled example scan (no setup needed)",
        description="Fit the bundled example scan (simulated, millimetres, Z-up) with its "
        "markers; write fit.glb, fit.ply and report.json; compare with the bundled truth.",
    )
    p.add_argument("--out-dir", default="out/demo", metavar="DIR", help="default: ./out/demo")
    p.add_argument("--fast", action="store_true", help="shorter schedule")
    p.add_argument("--quiet", action="store_true", help="no progress bar and no summary")
    p.set_defaults(func=_cmd_demo)


def _cmd_build_model(args: argparse.Namespace) -> int:
    from core.shapespace import build_model

    fits_dir = Path(args.fits_dir)
    if not fits_dir.is_dir():
        raise CliError(f"fits folder not found: {fits_dir}")
    features = Path(args.features) if args.features else fits_dir / "features.csv"
    features = _check_in_path(features, "features table")
    out = Path(args.out)
    if out.suffix.lower() != ".npz":
        raise CliError(f"--out must be a .npz file, got {out.name!r}")
    if not out.parent.is_dir():
        raise CliError(f"the folder of --out does not exist: {out.parent}")
    t0 = time.perf_counter()
    model = build_model(
        fits_dir, features, out, variance=args.variance, features=args.feature or None
    )
    if not args.quiet:
        print(f"built {out} in {time.perf_counter() - t0:.1f} s")
        print(json.dumps(_json_safe_summary(model.describe()), indent=2))
    return 0


def _json_safe_summary(d: dict) -> dict:
    return json.loads(json.dumps(json_ready(d), default=str))


def register_build_model(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "build-model",
        help="build a shape space (PCA per sex + feature map) from a folder of fits",
        description="Build a shape model from fitted bodies in template vertex order "
        "(*.npz with 'vertices', *.ply or *.obj; m or mm) and a table of subject features "
        "(CSV: id,sex,height_m,weight_kg[,age][,any measurement]).",
    )
    p.add_argument("fits_dir", metavar="FITS_DIR", help="folder of fit results")
    p.add_argument("--features", metavar="CSV", help="default: FITS_DIR/features.csv")
    p.add_argument("--out", required=True, metavar="MODEL.npz", help="where to write the model")
    p.add_argument("--variance", type=float, default=0.98, help="share of variance kept")
    p.add_argument(
        "--feature", action="append", metavar="NAME",
        help="a feature of the map (repeat; default height_m, weight_kg and age when present)",
    )  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no summary")
    p.set_defaults(func=_cmd_build_model)


# --------------------------------------------------------------------------- `from-measurements`


def read_measurements(path: Path | None, pairs: Sequence[str]) -> dict[str, Any]:
    """Measurements from a JSON file ``{name: value}`` and/or ``NAME=VALUE`` pairs (these win)."""
    values: dict[str, Any] = {}
    if path is not None:
        _check_in_path(path, "measurements file")
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as e:
            raise CliError(f"measurements file {str(path)!r} is not valid JSON: {e}") from None
        if not isinstance(data, dict):
            raise CliError(
                f"measurements file {str(path)!r} must hold one JSON object {{name: value}}"
            )
        values.update(data)
    for pair in pairs:
        name, sep, value = pair.partition("=")
        try:
            values[name.strip()] = float(value)
        except ValueError:
            sep = ""
        if not sep:
            raise CliError(
                f"--measure {pair!r}: expected NAME=VALUE with a number, e.g. stature=1.65"
            )
    if not values:
        raise CliError("give measurements: a JSON file {name: value} and/or --measure NAME=VALUE")
    return values


def _cmd_from_measurements(args: argparse.Namespace) -> int:
    from core.io import write_mesh
    from core.io.writers import atomic_write
    from core.matching.from_measurements import body_from_measurements

    values = read_measurements(
        Path(args.measurements) if args.measurements else None, args.measure or []
    )
    out = _check_out_path(Path(args.out))
    report_path = None
    if args.report is not None:
        report_path = _check_out_path(Path(args.report), (".json",), "--report")
    res = body_from_measurements(args.sex, values, calibrate=not args.no_calibrate)
    write_mesh(out, res.vertices, res.faces)
    report = {**res.report.to_dict(), "bodyspace_version": _version(), "outputs": [str(out)]}
    if report_path is not None:
        text = json.dumps(json_ready(report), indent=2, allow_nan=False)
        atomic_write(report_path, (text + "\n").encode("utf-8"))
    if not args.quiet:
        r = res.report
        cal = "" if r.calibrated else ", not calibrated"
        print(f"body ({args.sex}) from {len(r.given)} measurements in {r.seconds:.2f} s "
              f"({r.iterations} refinement steps{cal})")  # fmt: skip
        for name, m in r.matched.items():
            unit = m["unit"]
            f = (lambda v: f"{v:.1f} kg") if unit == "kg" else (lambda v: f"{v * 1000:.0f} mm")
            print(
                f"  {name:32s} given {f(m['given']):>9s}  body {f(m['given'] + m['residual']):>9s}"
            )
        for w in r.warnings:
            print(f"  warning: {w}")
        print("  wrote " + ", ".join([str(out)] + ([str(report_path)] if report_path else [])))
    return 0


def register_from_measurements(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "from-measurements",
        help="the most likely body from a few tape measurements",
        description="Make the most likely body of the default shape model with the given tape "
        "measurements (ANSUR II names, metres; weightkg in kg), e.g. "
        "'bodyspace from-measurements --sex female --measure stature=1.65 --measure "
        "weightkg=62 --out body.glb'. Writes the body (template vertex order, metres, +Y up).",
    )
    p.add_argument(
        "measurements", nargs="?", metavar="MEASUREMENTS.json",
        help="JSON object {ANSUR name: value}, e.g. {\"stature\": 1.65, \"weightkg\": 62}",
    )  # fmt: skip
    p.add_argument(
        "--measure", action="append", metavar="NAME=VALUE",
        help="a measurement (repeat; overrides the file's value of the same name)",
    )  # fmt: skip
    p.add_argument("--sex", required=True, choices=("female", "male"))
    p.add_argument("--out", required=True, metavar="BODY", help="the body: .ply, .obj or .glb")
    p.add_argument("--report", metavar="REPORT.json", help="write the JSON report here")
    p.add_argument(
        "--no-calibrate", action="store_true",
        help="the values follow bodyspace's measurement definitions (e.g. measured on a "
        "bodyspace body), not an ANSUR-style tape: match them as they are",
    )  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no summary")
    p.set_defaults(func=_cmd_from_measurements)


# --------------------------------------------------------------------------- `morph`


def _body_file_colours(path: Path) -> np.ndarray | None:
    """(13380, 3) uint8 per-vertex colours of a body file (PLY/OBJ with colours), else None."""
    if path.suffix.lower() not in (".ply", ".obj"):
        return None
    from core.io import read_mesh
    from core.template import load_template

    C = read_mesh(path).colors
    return C if C is not None and len(C) == load_template().n_vertices else None


def _cmd_morph(args: argparse.Namespace) -> int:
    from core.io import write_mesh
    from core.shapespace.build import read_body
    from core.transfer import MAX_BODIES, morph, morph_colors, morph_glb

    paths = [_check_in_path(Path(b), "body") for b in args.bodies]
    if not 2 <= len(paths) <= MAX_BODIES:
        raise CliError(f"give 2 to {MAX_BODIES} bodies, got {len(paths)}")
    out = Path(args.out)
    if not out.parent.is_dir():
        raise CliError(f"the folder of --out does not exist: {out.parent}")
    bodies = [read_body(p) for p in paths]
    colours = [_body_file_colours(p) for p in paths]
    if args.t is not None:
        if len(bodies) != 2:
            raise CliError(f"--t blends exactly two bodies, got {len(bodies)}")
        if not 0.0 <= args.t <= 1.0:
            raise CliError(f"--t must lie in [0, 1], got {args.t}")
        if out.suffix.lower() not in (".ply", ".obj", ".glb"):
            raise CliError(f"--out must end in .ply, .obj or .glb, got {out.name!r}")
        from core.template import load_template

        C = None
        if colours[0] is not None and colours[1] is not None:
            C = morph_colors(colours[0], colours[1], args.t)
        V = morph(bodies[0], bodies[1], args.t)
        write_mesh(out, V, load_template().F, colors=C)
        msg = f"wrote {out}: (1 - {args.t}) {paths[0].name} + {args.t} {paths[1].name}"
        msg += ", colours blended" if C is not None else ""
    else:
        if out.suffix.lower() != ".glb":
            raise CliError(f"--out must be a .glb file (morph targets), got {out.name!r}")
        from core.io.writers import atomic_write

        atomic_write(out, morph_glb(bodies, names=[p.stem for p in paths], colors=colours[0]))
        names = ", ".join(p.stem for p in paths[1:])
        msg = f"wrote {out}: {paths[0].stem} with morph targets {names}"
    if not args.quiet:
        print(msg)
    return 0


def register_morph(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "morph",
        help="blend bodies: a GLB with morph targets, or one in-between body (--t)",
        description="Bodies in template vertex order (*.ply, *.obj, *.npz with 'vertices'). "
        "Without --t: a GLB of the first body with one morph target per other body (names = "
        "file stems). With --t and two bodies: the body (1 - t) A + t B in the format of --out.",
    )
    p.add_argument("bodies", nargs="+", metavar="BODY", help="2-16 bodies (template order)")
    p.add_argument("--out", required=True, metavar="OUT", help="M.glb (or .ply/.obj with --t)")
    p.add_argument("--t", type=float, default=None, help="blend parameter in [0, 1]")
    p.add_argument("--quiet", action="store_true", help="no summary")
    p.set_defaults(func=_cmd_morph)


# --------------------------------------------------------------------------- `rig`, `pose`


def _cmd_rig(args: argparse.Namespace) -> int:
    from core.io.writers import atomic_write
    from core.shapespace.build import read_body
    from core.transfer.rig import rig_glb

    body = _check_in_path(Path(args.body), "body")
    out = Path(args.out)
    if out.suffix.lower() != ".glb":
        raise CliError(f"--out must be a .glb file, got {out.name!r}")
    if not out.parent.is_dir():
        raise CliError(f"the folder of --out does not exist: {out.parent}")
    atomic_write(out, rig_glb(read_body(body), method=args.joints))
    if not args.quiet:
        print(f"wrote {out}: {body.name} with the standard rig (163 joints, {args.joints})")
    return 0


def _cmd_pose(args: argparse.Namespace) -> int:
    from core.io import write_mesh
    from core.shapespace.build import read_body
    from core.template import load_template
    from core.transfer.rig import pose, posture, rotations_from_vectors
    from core.transfer.seat import SEATED_POSTURES

    body = _check_in_path(Path(args.body), "body")
    out = Path(args.out)
    if out.suffix.lower() not in (".ply", ".obj", ".glb"):
        raise CliError(f"--out must end in .ply, .obj or .glb, got {out.name!r}")
    if not out.parent.is_dir():
        raise CliError(f"the folder of --out does not exist: {out.parent}")
    if args.posture is None and args.rotations is None:
        raise CliError("give --posture NAME and/or --rotations R.json")
    rot = posture(args.posture) if args.posture else {}
    if args.rotations is not None:
        path = _check_in_path(Path(args.rotations), "rotations file")
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as e:
            raise CliError(f"rotations file {str(path)!r} is not valid JSON: {e}") from None
        if not isinstance(data, dict):
            raise CliError("the rotations file must hold {bone: [x, y, z] radians}")
        try:
            rot.update(rotations_from_vectors(data))
        except ValueError as e:
            raise CliError(str(e)) from None
    contact = args.seat_contact
    if contact is None:
        contact = args.posture in SEATED_POSTURES
    try:
        P = pose(read_body(body), rot, seat_contact=contact)
    except ValueError as e:  # seat contact in a posture without a seat
        raise CliError(str(e)) from None
    write_mesh(out, P, load_template().F)
    if not args.quiet:
        seat = ", on a seat" if contact else ""
        print(f"wrote {out}: {body.name} posed ({args.posture or 'rotations'}{seat})")
    return 0


def _cmd_texture(args: argparse.Namespace) -> int:
    from core.io import read_mesh
    from core.io.images import decode_image, encode_png
    from core.io.writers import atomic_write
    from core.shapespace.build import read_body
    from core.transfer.texture import bake_texture, textured_glb, write_textured_obj

    body = _check_in_path(Path(args.body), "body")
    out = _check_out_path(Path(args.out), (".png", ".glb", ".obj"))
    if not 16 <= args.size <= 8192:
        raise CliError(f"--size must be 16..8192 pixels, got {args.size}")
    V = read_body(body)
    if args.texture is not None:
        tex_path = _check_in_path(Path(args.texture), "texture")
        image = decode_image(tex_path.read_bytes(), name=tex_path.name)
        how = f"the texture {tex_path.name}"
    else:
        colours = read_mesh(body).colors if body.suffix.lower() != ".npz" else None
        if colours is None:
            raise CliError(
                f"{body.name} has no vertex colours to bake; give --texture T.png (a texture "
                "on the template UV layout, e.g. one this command baked from another body)"
            )
        image = bake_texture(colours, size=args.size)
        how = f"its colours baked ({args.size} px)"
    if out.suffix.lower() == ".png":
        atomic_write(out, encode_png(image))
    elif out.suffix.lower() == ".glb":
        textured_glb(out, V, image)
    else:
        write_textured_obj(out, V, image)
    if not args.quiet:
        print(f"wrote {out}: {body.name} with {how} on the template UV layout")
    return 0


JOINT_METHODS = ("regressor", "markers")  # = core.transfer.rig's (not imported: fast --help)
POSTURE_NAMES = ("standing", "seated", "driving", "reach")


def register_rig(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "rig",
        help="a skinned GLB of a body (the standard rig's joints placed on it)",
        description="A body in template vertex order (*.ply, *.obj, *.npz with 'vertices') as a "
        "GLB with a skin: 163 joints of the MakeHuman standard rig placed from the body's own "
        "vertices, inverse bind matrices, 4 skin weights per vertex.",
    )
    p.add_argument("body", metavar="BODY")
    p.add_argument("--out", required=True, metavar="R.glb")
    p.add_argument(
        "--joints", choices=JOINT_METHODS, default="regressor",
        help="joint placement: the rig's vertex-group regression (default, measured better) or "
        "a similarity fitted to each joint's surface markers",
    )  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no summary")
    p.set_defaults(func=_cmd_rig)

    p = subparsers.add_parser(
        "pose",
        help="pose a body: a named posture and/or bone rotations",
        description="Pose a body in template vertex order by linear blend skinning with the "
        "standard rig on its own joints; floor at y = 0.",
    )
    p.add_argument("body", metavar="BODY")
    p.add_argument("--posture", choices=POSTURE_NAMES, help="a named posture")
    p.add_argument(
        "--rotations", metavar="R.json",
        help="{bone: [x, y, z]} rotation vectors (radians, template axes), after the posture",
    )  # fmt: skip
    p.add_argument(
        "--seat-contact", action=argparse.BooleanOptionalAction, default=None,
        help="rest on a flat seat, the tissue under the buttocks compressed (default: on for "
        "seated and driving, off otherwise)",
    )  # fmt: skip
    p.add_argument("--out", required=True, metavar="OUT", help=".ply, .obj or .glb")
    p.add_argument("--quiet", action="store_true", help="no summary")
    p.set_defaults(func=_cmd_pose)


def register_texture(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "texture",
        help="bake a coloured body's texture, or dress a body in a texture",
        description="Every body shares the template's UV layout, so a texture moves from one "
        "body to any other. Without --texture: the body's vertex colours (a PLY of a coloured "
        "fit) baked into a texture; with --texture: that image (PNG/JPEG on the template UV "
        "layout) on this body. --out .png (the texture), .glb (textured) or .obj (+ .mtl, .png).",
    )
    p.add_argument("body", metavar="BODY", help="a body in template order (.ply, .obj, .npz)")
    p.add_argument("--texture", metavar="T.png", help="a texture on the template UV layout")
    p.add_argument("--size", type=int, default=1024, help="baked texture size in pixels")
    p.add_argument("--out", required=True, metavar="OUT", help=".png, .glb or .obj")
    p.add_argument("--quiet", action="store_true", help="no summary")
    p.set_defaults(func=_cmd_texture)


# --------------------------------------------------------------------------- parser, main

BUILTIN_COMMANDS: list[Registrar] = [
    register_fit,
    register_demo,
    register_build_model,
    register_from_measurements,
    register_morph,
    register_rig,
    register_texture,
]


def _plugin_registrars() -> list[Registrar]:
    """``register`` of each module in :data:`PLUGIN_MODULES` that exists."""
    out: list[Registrar] = []
    for name in PLUGIN_MODULES:
        try:
            mod = importlib.import_module(name)
        except ModuleNotFoundError as e:
            if e.name == name:  # the module itself is absent: nothing to register
                continue
            raise
        out.append(mod.register)
    return out


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Register a template human body to raw 3D body scans (Allen et al. 2003).",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    parser.add_argument("--debug", action="store_true", help="show full tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for register in [*BUILTIN_COMMANDS, *_plugin_registrars()]:
        register(sub)
    return parser


def _error(msg: str) -> None:
    msg = " ".join(str(msg).split())  # one line
    print(f"{PROG}: error: {msg}", file=sys.stderr)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``bodyspace`` console script; returns the exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv  # accepted anywhere on the line, for every subcommand
    argv = [a for a in argv if a != "--debug"]
    try:
        parser = build_parser()
    except Exception as e:  # a broken plugin module
        if debug:
            traceback.print_exc()
        _error(f"cannot set up the command line: {type(e).__name__}: {e}")
        return 1
    args = parser.parse_args(argv)
    if getattr(args, "func", None) is None:
        parser.print_help(sys.stderr)
        return 2
    from core.errors import BodyspaceError

    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        _error("interrupted")
        return 130
    except (CliError, BodyspaceError) as e:
        if debug:
            traceback.print_exc()
        _error(getattr(e, "message", None) or str(e))
        return 2
    except OSError as e:  # missing or unwritable files
        if debug:
            traceback.print_exc()
        where = f": {e.filename!r}" if e.filename else ""
        _error(f"{e.strerror or e}{where}")
        return 2
    except Exception as e:
        if debug:
            traceback.print_exc()
        _error(
            f"unexpected {type(e).__name__}: {e} (this is a bug; rerun with --debug for the "
            "traceback)"
        )
        return 1


if __name__ == "__main__":
    raise SystemExit(main())
