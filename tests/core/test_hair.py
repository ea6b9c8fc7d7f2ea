"""Hair on the head is found and left out of the markerless fit (``core.matching.hair``): it adds
no height, and a scan without hair has none labelled."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from bench.cases import make_case
from core.matching.hair import FLAT_HAIR_NOTE, find_hair, signed_offsets
from core.scan import Scan
from core.template import load_template


def _stature(V: np.ndarray) -> float:
    """Height (m) of the Vertex landmark above the soles (+Y up)."""
    return float(V[load_template().landmarks["Vertex"], 1] - V[:, 1].min())


def _with_bun(scan: Scan, truth: np.ndarray, radius: float = 0.05) -> tuple[Scan, int]:
    """The scan as a point cloud with a bun: a sphere of ``radius`` behind and above the back of
    the head (as ``core.synth.scanner_outputs.hair_volume`` draws one), its surface outside the
    head sampled as densely as the scan, the scalp under it hidden. Returns the scan and the
    bun's points."""
    tpl = load_template()
    L = tpl.landmarks
    F = np.asarray(tpl.F, dtype=np.int64)
    fwd = truth[L["Sellion"]] - truth[L["Opisthocranion"]]
    fwd[1] = 0.0
    fwd /= np.linalg.norm(fwd)
    c = truth[L["Opisthocranion"]] - 0.6 * radius * fwd + np.array([0.0, 0.04, 0.0])
    spacing = np.median(cKDTree(scan.V).query(scan.V, k=2)[0][:, 1])
    n = int(4 * np.pi * radius**2 / spacing**2)
    u = np.random.default_rng(0).normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    bun = c + radius * u
    outside = signed_offsets(bun, truth, F)[0] > 0.002
    bun, u = bun[outside], u[outside]
    keep = np.linalg.norm(scan.V - c, axis=1) > radius
    scan = Scan(
        V=np.vstack([scan.V[keep], bun]),
        F=None,
        normals=np.vstack([scan.normals[keep], u]),
        confidence=np.r_[scan.confidence[keep], np.ones(len(bun))],
        boundary=np.r_[scan.boundary[keep], np.zeros(len(bun), bool)],
        frame=scan.frame,
    )
    return scan, len(bun)


@pytest.fixture(scope="module")
def case():
    return make_case(105, small=True)


def test_no_hair_labelled_on_a_scan_without_hair(case):
    # around the true body and around a body shrunk 1 % (a fit a little small): nothing is hair
    assert find_hair(case.scan, case.truth).count == 0
    c = case.truth.mean(axis=0)
    assert find_hair(case.scan, c + 0.99 * (case.truth - c)).count == 0


def test_bun_adds_no_height_to_a_markerless_fit(case):
    from core.matching.markerless import fit_markerless
    from core.registration.schedule import Schedule

    scan, n_bun = _with_bun(case.scan, case.truth)
    res = fit_markerless(scan, schedule=Schedule.fast())
    err = abs(_stature(res.vertices) - _stature(case.truth))
    corr = np.linalg.norm(res.vertices - case.truth, axis=1).mean()
    # measured: stature 2.8 mm off, correspondence 2.7 mm mean (3.0 without the bun); with the
    # bun fitted as the head (no hair step): 25.8 mm and 9.5 mm
    assert err < 0.008, err * 1000
    assert corr < 0.005, corr * 1000
    warn = [w for w in res.report.warnings if w.startswith("hair volume on the head ignored")]
    assert len(warn) == 1, res.report.warnings
    assert FLAT_HAIR_NOTE in res.report.notes  # hair lying on the scalp is not found: said
    n_hair = res.report.removed["hair_points"]
    assert 0.8 * n_bun < n_hair <= n_bun + 20, (n_hair, n_bun)  # the bun, little else


@pytest.mark.parametrize(("seed", "hair"), [(312, True), (301, False)])
def test_hair_is_found_on_a_booth_mesh_and_nothing_else(tmp_path, seed, hair):
    # booth software's meshes (core.synth.scanner_outputs closed_booth: 10-15 k vertices, ~10 mm
    # apart): closed_booth-312's bun is 18 vertices beyond the true body, below the 30 points a
    # raw scan's hair cluster needs (found nowhere in the benchmark before HAIR_SPACING_M); the
    # limits follow the scan's spacing. closed_booth-301 has no hair: nothing is labelled.
    from core.io import load_scan
    from core.synth.scanner_outputs import make_case as make_real_case

    c = make_real_case(seed, "closed_booth")
    assert ("hair " in c.description) == hair
    scan, _ = load_scan(c.write(tmp_path / "scan.ply"))
    found = find_hair(scan, scan.frame.to_canonical(c.truth))
    assert (found.count >= 10) if hair else (found.count == 0), found.count


@pytest.mark.parametrize("seed", [326, 316])
def test_a_coarse_bun_or_ponytail_is_found_whole(tmp_path, seed):
    # booth meshes draw hair volume with vertices farther apart than the link distance: linked by
    # distance alone, closed_booth-326's bun was found as one cluster of 29 of its 111 vertices,
    # and the other 77 (14-86 mm off the skull) made the fit's head read suspect (head scan→fit
    # p95 34 mm; the head 4 mm off the truth). The scan's triangles link the hair's vertices too.
    from core.geometry import MeshDistance
    from core.io import load_scan
    from core.synth.scanner_outputs import make_case as make_real_case

    tpl = load_template()
    c = make_real_case(seed, "closed_booth")
    assert "hair bun" in c.description or "hair ponytail" in c.description
    scan, _ = load_scan(c.write(tmp_path / "scan.ply"))
    truth = scan.frame.to_canonical(c.truth)
    found = find_hair(scan, truth)
    d = MeshDistance(truth, np.asarray(tpl.F, np.int64), k=8).distances(scan.V)
    near_head = np.linalg.norm(scan.V - truth[tpl.part_mask("head")].mean(axis=0), axis=1) < 0.3
    kept = near_head & ~found.points
    # measured: kept points at most 6.5 / 6.3 mm from the true skull, 111 / 199 hair points
    assert d[kept].max() < 0.010, d[kept].max() * 1000  # no hair left on the head
    assert not (found.points & (d < 0.003)).any()  # no skin taken for hair
