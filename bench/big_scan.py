"""Big scans: a ~2.2 M-vertex binary PLY against the same body's ~144 k-vertex scan.

``python -m bench.big_scan [--out DIR]``: simulates one body's scan (4 mm pitch, 144 k vertices),
subdivides it to ~2.2 M vertices (the same surface, as a dense scanner gives it), writes both as
binary PLY without normals or confidence, then for each, in its own process:

- ``bodyspace fit SCAN --markers M`` end to end (CPU s = user + sys of the process, imports
  included; peak RSS from wait4);
- loading alone: ``core.io.read_mesh`` and ``trimesh.load(process=False)`` (the library one
  would otherwise use), CPU s of the call and the process's peak RSS.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np


def make_scans(out: Path, seed: int = 3) -> tuple[Path, Path, Path]:
    import trimesh

    from core.io import write_markers_csv, write_ply
    from core.synth import ScanConfig, random_body, simulate_scan
    from core.template import load_template

    rng = np.random.default_rng(seed)
    tpl = load_template()
    body = random_body(rng, pose=False)
    sim = simulate_scan(body.V, tpl.F, rng, config=ScanConfig(), landmarks=tpl.landmarks)
    small, big, markers = out / "scan_small.ply", out / "scan_big.ply", out / "markers.csv"
    write_ply(small, sim.V_scan, sim.F_scan)
    write_markers_csv(markers, sim.markers)
    V, F = sim.V_scan, sim.F_scan
    while len(V) < 2_000_000:
        V, F = trimesh.remesh.subdivide(V, F)
    write_ply(big, V, F)
    return small, big, markers


def run(args: list[str]) -> tuple[float, float, str]:
    """(CPU s, peak RSS MB, stdout) of a child process."""
    p = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    out = p.stdout.read()  # type: ignore[union-attr]
    _, status, ru = os.wait4(p.pid, 0)
    if status != 0:
        raise RuntimeError(f"{args} failed:\n{out}")
    return ru.ru_utime + ru.ru_stime, ru.ru_maxrss / 1024, out


_TIMED = (
    "import sys, time\n{imp}\nt = time.process_time()\n{call}\n"
    "hwm = [ln for ln in open('/proc/self/status') if ln.startswith('VmHWM:')][0].split()[1]\n"
    "print(time.process_time() - t, int(hwm) / 1024)\n"
)
#: loading alone, timed inside the child (imports excluded), peak RSS of the child (VmHWM)
LOAD = {
    "bodyspace": _TIMED.format(imp="from core.io import read_mesh", call="read_mesh(sys.argv[1])"),
    "trimesh": _TIMED.format(imp="import trimesh", call="trimesh.load(sys.argv[1], process=False)"),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", type=Path, default=None, help="folder for the scans (default tmp)")
    a = ap.parse_args()
    out = a.out or Path(tempfile.mkdtemp(prefix="bigscan-"))
    out.mkdir(parents=True, exist_ok=True)
    py = sys.executable
    # made in a child: ru_maxrss is inherited across fork/exec, so this process stays small
    subprocess.run([py, "-c", f"from bench.big_scan import make_scans; from pathlib import Path; "
                    f"make_scans(Path({str(out)!r}))"], check=True)  # fmt: skip
    small, big, markers = out / "scan_small.ply", out / "scan_big.ply", out / "markers.csv"
    rows = {}
    for name, scan in (("small", small), ("big", big)):
        report = out / f"{name}.json"
        cpu, rss, _ = run([py, "-m", "service.cli", "fit", str(scan), "--markers", str(markers),
                           "--out", str(out / f"{name}.glb"), "--report", str(report)])  # fmt: skip
        r = json.loads(report.read_text())
        rows[name] = dict(
            vertices=int(r["scan_vertices"]), fit_cpu_s=round(cpu, 2), fit_peak_mb=round(rss),
            scan_to_fit_mean_mm=round(1000 * r["scan_to_fit_mean_m"], 2),
            scan_to_fit_p95_mm=round(1000 * r["scan_to_fit_p95_m"], 2),
            no_data_fraction=round(r["no_data_fraction"], 3),
            file_mb=round(scan.stat().st_size / 1e6),
        )  # fmt: skip
        for lib, code in LOAD.items():
            _, _, text = run([py, "-c", code, str(scan)])
            cpu, rss = (float(x) for x in text.split()[-2:])
            rows[name][f"load_{lib}_cpu_s"] = round(cpu, 2)
            rows[name][f"load_{lib}_peak_mb"] = round(rss)
    for name, row in rows.items():
        print(name, json.dumps(row))
    print(f"fit CPU ratio big/small: {rows['big']['fit_cpu_s'] / rows['small']['fit_cpu_s']:.2f}")


if __name__ == "__main__":
    main()
