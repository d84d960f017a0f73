"""Mesh loading, validation, subdivision and the embedded face."""

import numpy as np
import pytest

from polarbssrdf.geometry import SurfaceMesh, face_mesh, face_region_masks, load_mesh, subdivide, uv_sphere


def surface_area(mesh):
    c = mesh.vertices[mesh.faces]
    return 0.5 * np.linalg.norm(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), axis=1).sum()


def test_face_mesh_is_in_millimetres_and_faces_the_viewer():
    mesh = face_mesh(0)
    assert mesh.vertices.shape == (468, 3) and mesh.faces.shape == (898, 3)
    extent = mesh.vertices.max(0) - mesh.vertices.min(0)
    assert 120 < extent[0] < 200 and 150 < extent[1] < 220  # a face is ~15 cm wide, ~18 cm tall
    normals = mesh.vertex_normals()
    assert np.mean(normals[:, 2] > 0) > 0.9  # +z toward the viewer


def test_subdivision_keeps_the_surface_and_the_parameterization():
    mesh = face_mesh(0)
    fine = subdivide(mesh, 2)
    assert len(fine.faces) == 16 * len(mesh.faces)
    assert surface_area(fine) == pytest.approx(surface_area(mesh), rel=1e-10)
    # original vertices keep their positions and UVs
    np.testing.assert_allclose(fine.vertices[:468], mesh.vertices)
    np.testing.assert_allclose(fine.uvs[:468], mesh.uvs)


def test_uv_sphere_area_and_orientation():
    sphere = uv_sphere(radius_mm=40.0, rings=64, segments=128)
    assert surface_area(sphere) == pytest.approx(4 * np.pi * 40.0**2, rel=5e-3)
    c = sphere.vertices[sphere.faces]
    outward = np.sum(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]) * c.mean(1), axis=1)
    assert np.all(outward > 0)


def test_face_regions_lie_on_the_face_and_do_not_overlap():
    masks = face_region_masks(128)
    assert masks["forehead"].sum() > 100 and masks["cheek_left"].sum() > 50
    assert not np.any(masks["forehead"] & masks["cheeks"])
    assert not np.any(masks["cheek_left"] & masks["cheek_right"])
    rows = np.nonzero(masks["forehead"])[0]
    cheek_rows = np.nonzero(masks["cheeks"])[0]
    assert rows.mean() < cheek_rows.mean()  # row 0 is the top of the map: forehead above cheeks


def write_obj(path, vertices, faces, uvs=None):
    lines = [f"v {x} {y} {z}" for x, y, z in vertices]
    if uvs is not None:
        lines += [f"vt {u} {v}" for u, v in uvs]
        lines += [f"f {a + 1}/{a + 1} {b + 1}/{b + 1} {c + 1}/{c + 1}" for a, b, c in faces]
    else:
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    path.write_text("\n".join(lines) + "\n")


QUAD = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
QUAD_FACES = np.array([[0, 1, 2], [0, 2, 3]])
QUAD_UV = QUAD[:, :2]


def test_loading_errors_name_the_problem(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.obj"):
        load_mesh(tmp_path / "missing.obj")
    write_obj(tmp_path / "no_uv.obj", QUAD, QUAD_FACES)
    with pytest.raises(ValueError, match="texture coordinates"):
        load_mesh(tmp_path / "no_uv.obj")
    write_obj(tmp_path / "ok.obj", QUAD, QUAD_FACES, QUAD_UV)
    assert load_mesh(tmp_path / "ok.obj", scale_to_mm=10).vertices.max() == pytest.approx(10)


@pytest.mark.parametrize("change,message", [
    (lambda v, f, uv: (v, f, uv * 1.5), "UVs must lie in"),
    (lambda v, f, uv: (np.where(v == 1, np.nan, v), f, uv), "NaN"),
    (lambda v, f, uv: (v, np.array([[0, 1, 2], [0, 0, 3]]), uv), "degenerate"),
    (lambda v, f, uv: (v, f, np.array([[0, 0], [0.5, 0.5], [1, 1], [0, 1.0]])), "zero UV area"),
    (lambda v, f, uv: (v, f + 1, uv), "face indices"),
    (lambda v, f, uv: (v, f, uv[:3]), "one UV per vertex"),
])
def test_validation(change, message):
    with pytest.raises(ValueError, match=message):
        SurfaceMesh(*change(QUAD, QUAD_FACES, QUAD_UV))
