"""VTK PolyData reader: every OpenSim bone mesh in the data, fan triangulation, malformed files."""

import re

import numpy as np
import pytest

from biomotion.errors import DataFormatError
from biomotion.io.vtp import read_vtp
from tests.conftest import DATA_ROOT


def _signed_volume(vertices: np.ndarray, triangles: np.ndarray) -> float:
    """Enclosed volume by the divergence theorem: positive when faces wind counter-clockwise seen from outside."""
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def _boundary_edges(triangles: np.ndarray) -> int:
    edges = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return int((counts == 1).sum())


def test_every_vtp_in_the_data(data_root):
    files = sorted(DATA_ROOT.glob("opensim-models/**/*.vtp"))
    assert len(files) == 21  # SOURCE.md: 12 shared + 9 Rajagopal meshes
    volumes = {}
    for path in files:
        vertices, triangles = read_vtp(path)
        text = path.read_text()
        declared = int(re.search(r'NumberOfPoints="(\d+)"', text)[1])
        polys = text[text.index("<Polys>") : text.index("</Polys>")]
        offsets = np.array(re.search(r'Name="offsets"[^>]*>([^<]*)<', polys)[1].split(), dtype=int)
        sizes = np.diff(np.concatenate([[0], offsets]))
        assert vertices.shape == (declared, 3), path
        assert triangles.shape == (int((sizes - 2).sum()), 3), path  # a polygon of n vertices gives n - 2
        assert np.unique(triangles).size == declared, path  # every point is used by a face
        assert np.ptp(vertices, axis=0).max() < 0.6, path  # metres: no bone is longer than 60 cm
        volumes[path.name] = _signed_volume(vertices, triangles)
        assert volumes[path.name] > 0, path  # winding kept: normals point out
    for closed in (
        "r_femur.vtp",
        "l_femur.vtp",
        "r_talus.vtp",
        "r_patella.vtp",
        "r_bofoot.vtp",
        "sacrum.vtp",
        "hat_ribs_scap.vtp",
    ):
        assert _boundary_edges(read_vtp(next(p for p in files if p.name == closed))[1]) == 0, closed
    for name in ("talus", "bofoot", "foot", "fibula", "pelvis", "patella"):
        assert volumes[f"l_{name}.vtp"] == pytest.approx(volumes[f"r_{name}.vtp"], rel=0.01), name  # mirror pairs
    assert 300e-6 < volumes["r_femur.vtp"] < 450e-6  # an adult femur encloses roughly 0.3-0.45 litre


VTP = """<?xml version="1.0"?>
<VTKFile type="PolyData" version="0.1">
  <PolyData>
    <Piece NumberOfPoints="{n}" NumberOfPolys="{polys}">
      <Points><DataArray type="Float32" NumberOfComponents="3" format="{fmt}">{points}</DataArray></Points>
      <Polys>
        <DataArray type="Int32" Name="connectivity" format="ascii">{conn}</DataArray>
        <DataArray type="Int32" Name="offsets" format="ascii">{offsets}</DataArray>
      </Polys>
    </Piece>
  </PolyData>
</VTKFile>
"""
PENTAGON = dict(
    n=6,
    polys=2,
    fmt="ascii",
    points=" ".join(["0 0 0", "1 0 0", "1.3 1 0", "0.5 1.6 0", "-0.3 1 0", "0 0 1"]),
    conn="0 1 2 3 4  0 1 5",
    offsets="5 8",
)


def test_polygons_become_fans(tmp_path):
    path = tmp_path / "pentagon.vtp"
    path.write_text(VTP.format(**PENTAGON))
    vertices, triangles = read_vtp(path)
    assert vertices.shape == (6, 3) and vertices[2].tolist() == [1.3, 1.0, 0.0]
    assert triangles.tolist() == [[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 1, 5]]


@pytest.mark.parametrize(
    "change, message",
    [
        (dict(fmt="binary"), "only ASCII"),
        (dict(n=7), "18 coordinates for NumberOfPoints=7"),
        (dict(conn="0 1 2 3 9  0 1 5"), "out of range"),
        (dict(offsets="5 9"), "does not match 8 indices"),
        (dict(conn="0 1 2 3 4  0 1 5", offsets="2 8"), "polygon 0 has 2 vertices"),
        (dict(offsets="5"), "1 offsets for NumberOfPolys=2"),
        (dict(points="0 0 0 1 0 0 1.3 1 0 0.5 1.6 0 -0.3 1 0 0 0 x"), "bad number"),
    ],
)
def test_malformed_files_name_the_field(tmp_path, change, message):
    path = tmp_path / "bad.vtp"
    path.write_text(VTP.format(**{**PENTAGON, **change}))
    with pytest.raises(DataFormatError, match=message) as error:
        read_vtp(path)
    assert error.value.path == path and error.value.field.startswith("Piece[0]")


def test_not_xml_and_not_polydata(tmp_path):
    path = tmp_path / "broken.vtp"
    path.write_text('<?xml version="1.0"?>\n<VTKFile type="PolyData">\n<PolyData>\n</VTKFile>\n')
    with pytest.raises(DataFormatError, match="not well-formed XML") as error:
        read_vtp(path)
    assert error.value.line == 4
    path.write_text('<VTKFile type="UnstructuredGrid"/>')
    with pytest.raises(DataFormatError, match="not a VTK PolyData"):
        read_vtp(path)
    with pytest.raises(DataFormatError, match="no such file"):
        read_vtp(tmp_path / "missing.vtp")
