"""Colour transfer: a body painted with smooth colours, scanned with colour by the simulator
(holes, 2 % colour noise), written as a coloured PLY, read back and fitted; the fitted body's
colours match the paint with mean error < 5 % of the range where the scan saw the body and
< 15 % in the holes (filled harmonically)."""

from __future__ import annotations

import numpy as np
import pytest

from core.io import load_scan, write_markers_csv, write_ply
from core.registration.fit import fit
from core.registration.schedule import Schedule
from core.synth import ScanConfig, random_body, simulate_scan
from core.template import load_template
from core.transfer.colour import harmonic_fill, transfer_colours


def paint(T: np.ndarray) -> np.ndarray:
    """(n, 3) smooth colours in [0.1, 0.9] from template rest positions T (metres)."""
    x, y, z = T.T
    return 0.5 + 0.4 * np.stack(
        [np.sin(6 * x + 2 * y), np.cos(4 * y + 3 * z), np.sin(5 * z + 3 * x + y)], axis=1
    )


@pytest.fixture(scope="module")
def coloured_fit(tmp_path_factory):
    tpl = load_template()
    rng = np.random.default_rng(7)
    body = random_body(rng, sex="female")
    C = paint(tpl.V)
    sim = simulate_scan(body.V, tpl.F, rng, config=ScanConfig.small(), colors=C)
    d = tmp_path_factory.mktemp("colour")
    write_ply(d / "scan.ply", sim.V_scan, sim.F_scan, colors=sim.colors)
    write_markers_csv(d / "markers.csv", sim.markers)
    scan, markers = load_scan(d / "scan.ply", markers_path=d / "markers.csv")
    res = fit(scan, markers, schedule=Schedule.fast())
    # the truth: template vertices the scanner did not see (no scan point within 1 cm)
    from scipy.spatial import cKDTree

    unseen = cKDTree(sim.V_scan).query(body.V)[0] > 0.01
    return C, scan, res, unseen


def test_scan_keeps_colour(coloured_fit):
    _, scan, _, _ = coloured_fit
    assert scan.colors is not None and scan.colors.shape == (len(scan.V), 3)
    assert scan.colors.dtype == np.uint8 and scan.colors.std() > 20


def test_colours_transferred_back(coloured_fit):
    C, scan, res, unseen = coloured_fit
    got, observed = transfer_colours(res.vertices, scan)
    err = np.abs(got - C).mean(axis=1) / 0.8  # fraction of the painted range
    assert unseen.sum() > 200, unseen.sum()  # the scan has holes (crown, soles, armpits, blobs)
    assert (~observed[unseen]).mean() > 0.5  # most unseen vertices are filled, not sampled
    assert err[~unseen].mean() < 0.05, err[~unseen].mean()
    assert err[unseen].mean() < 0.15, err[unseen].mean()


def test_harmonic_fill_is_exact_for_linear_data_on_a_path():
    # a path graph 0-1-2-3-4 with the ends known: the harmonic fill is linear in between
    E = np.array([[0, 1], [1, 2], [2, 3], [3, 4]])
    vals = np.zeros((5, 1))
    vals[0], vals[4] = 1.0, 3.0
    known = np.array([True, False, False, False, True])
    out = harmonic_fill(vals, known, E)
    np.testing.assert_allclose(out[:, 0], [1.0, 1.5, 2.0, 2.5, 3.0], atol=1e-6)


def test_uncoloured_scan_is_refused(coloured_fit):
    from dataclasses import replace

    _, scan, res, _ = coloured_fit
    with pytest.raises(ValueError, match="no colours"):
        transfer_colours(res.vertices, replace(scan, colors=None))


def test_obj_vertex_colours_reach_the_scan(coloured_fit, tmp_path):
    """OBJ ``v x y z r g b`` (floats in [0, 1]) -> Scan.colors, the same colours as the PLY."""
    _, scan, _, _ = coloured_fit
    from core.io import load_scan
    from core.io.writers import atomic_write

    V, C = scan.V, scan.colors
    lines = [f"v {x:.6f} {y:.6f} {z:.6f} {r / 255:.6f} {g / 255:.6f} {b / 255:.6f}"
             for (x, y, z), (r, g, b) in zip(V, C, strict=True)]  # fmt: skip
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in scan.F]
    atomic_write(tmp_path / "scan.obj", ("\n".join(lines) + "\n").encode())
    obj, _ = load_scan(tmp_path / "scan.obj", units="m", up="+y")
    assert obj.colors is not None and len(obj.colors) == len(obj.V)
    # same points (cleaning may reorder nothing here): colours within one step of 255
    from scipy.spatial import cKDTree

    d, j = cKDTree(V).query(obj.V)
    assert d.max() < 1e-5
    assert np.abs(obj.colors.astype(int) - C[j].astype(int)).max() <= 1
