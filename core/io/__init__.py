"""Scan, marker and mesh I/O: readers, units/up-axis frames, scan preparation, writers."""

from core.io.frame import apply_frame, detect_frame, turn_over
from core.io.markers import read_markers, write_markers_csv
from core.io.prepare import load_scan, prepare_scan
from core.io.readers import inspect_mesh_header, read_mesh
from core.io.writers import write_glb, write_mesh, write_obj, write_ply

__all__ = [
    "apply_frame",
    "detect_frame",
    "inspect_mesh_header",
    "load_scan",
    "prepare_scan",
    "read_markers",
    "read_mesh",
    "turn_over",
    "write_glb",
    "write_markers_csv",
    "write_mesh",
    "write_obj",
    "write_ply",
]
