"""Sections of non-convex shapes are traced along the mesh (issue 30, finding 1)."""

import numpy as np
import pytest

from capsim.numerics.mesh import rest_shape_mesh, rotation_about_z, unit_sphere_mesh
from capsim.face.plot import _arc_length_from_largest_x, _shoelace, section_loops, xy_section


def _segments_cross(p: np.ndarray) -> int:
    """How many pairs of non-adjacent segments of the closed polygon p cross."""
    a, b = p[:, :2], np.roll(p[:, :2], -1, axis=0)
    n = len(a)

    def orient(p, q, r):
        return np.sign((q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0]))

    A, B = a[:, None], b[:, None]
    C, D = a[None, :], b[None, :]
    crossing = (orient(A, B, C) * orient(A, B, D) < 0) & (orient(C, D, A) * orient(C, D, B) < 0)
    i, j = np.triu_indices(n, 2)
    adjacent = (j - i == 1) | ((i == 0) & (j == n - 1))
    return int(crossing[i[~adjacent], j[~adjacent]].sum())


@pytest.fixture(scope="module")
def s_shaped_red_cell():
    """A biconcave cell (axis y) bent into an S in the shear plane and turned by 20°, as a
    red cell at λ = 5 is: y → y + β sin(πx/R) keeps every area of the z = 0 plane, so
    its cut encloses the rest cut's area, R² ∫ √(1−s²)(c0 + c2 s² + c4 s⁴) ds over [−1, 1]
    = R² π (c0/2 + c2/8 + c4/16) (R: the rim radius, the mesh's largest x at rest)."""
    mesh = rest_shape_mesh("biconcave", level=2)
    x = mesh.positions.copy()
    R = float(x[:, 0].max())
    x[:, 1] += 0.35 * np.sin(np.pi * x[:, 0] / R)
    x = x @ rotation_about_z(np.deg2rad(20.0)).T
    area = R**2 * np.pi * (0.207 / 2 + 2.003 / 8 - 1.123 / 16)
    # the exact cut, densely: half-thickness R/2 √(1−s²)(c0 + c2 s² + c4 s⁴) at x = R s, bent and turned
    s = np.cos(np.linspace(0.0, np.pi, 20001))
    h = 0.5 * R * np.sqrt(1.0 - s**2) * (0.207 + 2.003 * s**2 - 1.123 * s**4)
    xs = np.concatenate([R * s, R * s])
    ys = np.concatenate([h, -h]) + 0.35 * np.sin(np.pi * xs / R)
    exact = np.stack([xs, ys, 0 * xs], 1) @ rotation_about_z(np.deg2rad(20.0)).T
    return x, mesh.elements, area, exact[:, :2]


def _far_from(points: np.ndarray, curve: np.ndarray) -> np.ndarray:
    """Distance of each point (n, 2) from the densely sampled curve (m, 2)."""
    return np.sqrt(((points[:, None, :] - curve[None, :, :]) ** 2).sum(-1)).min(axis=1)


def test_an_s_shaped_cut_is_traced_not_zig_zagged(s_shaped_red_cell):
    x, elements, area, exact = s_shaped_red_cell
    p, v = xy_section(x, elements, 0.0, values=x[:, 0], curved=True)
    midpoints = 0.5 * (p[:, :2] + np.roll(p[:, :2], -1, axis=0))
    assert _far_from(midpoints, exact).max() < 0.02  # no segment cuts across the cell
    assert _segments_cross(p) == 0
    assert _shoelace(p) == pytest.approx(area, rel=0.01)
    assert np.linalg.norm(np.diff(p, axis=0, append=p[:1]), axis=1).max() < 0.15  # a sixth of an element side
    assert np.allclose(v, p[:, 0])
    # the cut is not star-shaped about its mean: ordering by angle cuts across the cell
    c = p.mean(axis=0)
    by_angle = p[np.argsort(np.arctan2(p[:, 1] - c[1], p[:, 0] - c[0]))]
    assert _far_from(0.5 * (by_angle[:, :2] + np.roll(by_angle[:, :2], -1, axis=0)), exact).max() > 0.1


def test_sections_are_closed_loops_with_the_right_areas():
    sphere = unit_sphere_mesh("octahedron", 3)
    for z0 in (0.0, 0.3, -0.7):
        loops = section_loops(sphere.positions, sphere.elements, z0)
        assert len(loops) == 1
        p, _ = loops[0]
        assert _shoelace(p) == pytest.approx(np.pi * (1 - z0**2), rel=1e-3)  # counter-clockwise
        assert np.allclose(p[:, 2], z0)
    # a plane above the surface meets nothing: an error, not an empty figure
    disk = rest_shape_mesh("biconcave", level=2, axis=(0.0, 0.0, 1.0))
    top = disk.positions[:, 2].max()
    with pytest.raises(ValueError, match="does not meet"):
        section_loops(disk.positions, disk.elements, 1.01 * top)


def test_tensions_run_along_the_arc_length():
    s = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    p = np.stack([np.cos(s + 1.0), np.sin(s + 1.0), 0 * s], 1)
    arc, v = _arc_length_from_largest_x(p, p[:, :1])
    assert arc[0] == 0.0 and arc[-1] == 1.0 and np.all(np.diff(arc) > 0)
    assert v[0, 0] == v[-1, 0] == p[:, 0].max()


def _cut_area_from_flat_pieces(x: np.ndarray, elements: np.ndarray, n: int = 8, rows: int = 800) -> float:
    """Area of the z = 0 cut measured without ordering anything: every curved element split
    into n² flat triangles, each crossing triangle's straight piece of the cut collected,
    and the area summed as chords along rows y = const (the crossings of a row sorted in x,
    pairs inside)."""
    from capsim.face.plot import _quadratic_shape

    grid = [(i, j) for j in range(n + 1) for i in range(n + 1 - j)]
    index = {ij: k for k, ij in enumerate(grid)}
    tris = []
    for (i, j) in grid:
        if (i + 1, j) in index and (i, j + 1) in index:
            tris.append((index[(i, j)], index[(i + 1, j)], index[(i, j + 1)]))
        if (i + 1, j + 1) in index:
            tris.append((index[(i + 1, j)], index[(i + 1, j + 1)], index[(i, j + 1)]))
    uv = np.array(grid, float) / n
    pts = np.einsum("pk,ekd->epd", _quadratic_shape(uv[:, 0], uv[:, 1]), x[elements]).reshape(-1, 3)
    offset = (np.arange(len(elements)) * len(grid))[:, None, None]
    tri = (np.array(tris)[None] + offset).reshape(-1, 3)
    z = pts[:, 2]
    segments = []
    for a, b, c in tri:
        ends = []
        for p, q in ((a, b), (b, c), (c, a)):
            if (z[p] >= 0) != (z[q] >= 0):
                s = z[p] / (z[p] - z[q])
                ends.append(pts[p, :2] + s * (pts[q, :2] - pts[p, :2]))
        if len(ends) == 2:
            segments.append(ends)
    seg = np.array(segments)                                   # (S, 2, 2)
    y0, y1 = seg[:, :, 1].min(), seg[:, :, 1].max()
    ys = y0 + (np.arange(rows) + 0.5) * (y1 - y0) / rows
    area = 0.0
    for y in ys:
        ya, yb = seg[:, 0, 1], seg[:, 1, 1]
        hit = (ya >= y) != (yb >= y)
        t = (y - ya[hit]) / (yb[hit] - ya[hit])
        xs = np.sort(seg[hit, 0, 0] + t * (seg[hit, 1, 0] - seg[hit, 0, 0]))
        area += float((xs[1::2] - xs[0::2]).sum())
    return area * (y1 - y0) / rows


@pytest.fixture(scope="module")
def red_cell_at_lambda_5(tmp_path_factory):
    """configs/rbc.yaml at level 2 (λ = 5, Skalak, bending), run to kt = 4: its cut is an S."""
    from capsim.config import apply_overrides, load_case
    from capsim.runs.runner import run_case
    from capsim.storage.store import read_trajectory

    path = tmp_path_factory.mktemp("rbc") / "rbc.h5"
    case = apply_overrides(load_case("configs/rbc.yaml"), **{
        "mesh.level": 2, "time.t_end": 4.0, "output.path": str(path), "output.snapshot_every": 4.0})
    assert run_case(case)["status"] == "completed"
    data = read_trajectory(path)
    return np.asarray(data["positions"][-1]), np.asarray(data["elements"])


def test_a_red_cell_deformed_at_lambda_5_is_traced_with_the_mesh_area(red_cell_at_lambda_5):
    x, elements = red_cell_at_lambda_5
    p, _ = xy_section(x, elements, 0.0, curved=True)
    assert _segments_cross(p) == 0
    assert _shoelace(p) == pytest.approx(_cut_area_from_flat_pieces(x, elements), rel=0.01)
    # not star-shaped: the angle order about the mean would have enclosed another area
    c = p.mean(axis=0)
    by_angle = p[np.argsort(np.arctan2(p[:, 1] - c[1], p[:, 0] - c[0]))]
    assert abs(_shoelace(by_angle) / _cut_area_from_flat_pieces(x, elements) - 1.0) > 0.02
