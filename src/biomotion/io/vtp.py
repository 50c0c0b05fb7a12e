"""VTK XML PolyData (``.vtp``) surface meshes, ASCII encoding: OpenSim's bone geometry.

The format is VTK's XML file format (Kitware, *The VTK User's Guide*, 11th ed., chapter "VTK File Formats",
section "XML File Formats"): a ``<VTKFile type="PolyData">`` holds one or more ``<Piece>`` elements, each with
``<Points>`` (one Float ``DataArray`` of ``NumberOfPoints`` x 3 coordinates) and ``<Polys>`` (two Int
``DataArray``s: ``connectivity``, the point indices of every polygon one after the other, and ``offsets``, the
end of each polygon in ``connectivity``). OpenSim's meshes are ASCII, polygons of 3 to 10 vertices, no normals.

Polygons are split into triangles as fans from their first vertex, which is exact for the convex faces these
meshes hold and keeps the polygon's winding (so the outward side stays outward).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from biomotion.errors import DataFormatError
from biomotion.io.xml import parse_tree


def read_vtp(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices [V, 3] (float64, file units: metres for OpenSim) and triangles [F, 3] (int64) of a ``.vtp`` file.

    Every ``<Piece>`` is read and their meshes concatenated. Vertices, lines and triangle strips are not surfaces
    made of polygons: a file holding strips is refused; vertex and line cells are ignored.
    """
    path = Path(path)
    root = parse_tree(path).getroot()  # DataFormatError for a missing, malformed or DOCTYPE-bearing file
    if root.tag != "VTKFile" or root.get("type") != "PolyData":
        raise DataFormatError(
            path, f"not a VTK PolyData file (root <{root.tag} type={root.get('type')!r}>)", field="VTKFile"
        )
    pieces = root.findall("./PolyData/Piece")
    if not pieces:
        raise DataFormatError(path, "no <PolyData><Piece> element", field="Piece")
    vertices, triangles, count = [], [], 0
    for number, piece in enumerate(pieces):
        points, faces = _piece(path, piece, number)
        vertices.append(points)
        triangles.append(faces + count)
        count += len(points)
    return np.concatenate(vertices), np.concatenate(triangles)


def _piece(path: Path, piece: ET.Element, number: int) -> tuple[np.ndarray, np.ndarray]:
    where = f"Piece[{number}]"
    if int(piece.get("NumberOfStrips", "0") or 0) > 0:
        raise DataFormatError(path, "triangle strips are not supported (only polygons)", field=f"{where}/Strips")
    n_points = _count(path, piece, "NumberOfPoints", where)
    n_polys = _count(path, piece, "NumberOfPolys", where)
    point_array = piece.find("./Points/DataArray")
    if point_array is None:
        raise DataFormatError(path, "no <Points><DataArray>", field=f"{where}/Points")
    if point_array.get("NumberOfComponents", "1") != "3":
        raise DataFormatError(path, "points must have 3 components", field=f"{where}/Points")
    points = _numbers(path, point_array, f"{where}/Points")
    if points.size != 3 * n_points:
        raise DataFormatError(
            path,
            f"{points.size} coordinates for NumberOfPoints={n_points} (expected {3 * n_points})",
            field=f"{where}/Points",
        )
    if not np.all(np.isfinite(points)):
        raise DataFormatError(path, "non-finite point coordinate", field=f"{where}/Points")
    arrays = {array.get("Name"): array for array in piece.findall("./Polys/DataArray")}
    if n_polys == 0:
        return points.reshape(-1, 3), np.zeros((0, 3), dtype=np.int64)
    missing = [name for name in ("connectivity", "offsets") if name not in arrays]
    if missing:
        raise DataFormatError(path, f"<Polys> lacks DataArray {', '.join(missing)}", field=f"{where}/Polys")
    connectivity = _numbers(path, arrays["connectivity"], f"{where}/Polys/connectivity", integer=True)
    offsets = _numbers(path, arrays["offsets"], f"{where}/Polys/offsets", integer=True)
    return points.reshape(-1, 3), _triangulate(path, connectivity, offsets, n_points, n_polys, where)


def _count(path: Path, piece: ET.Element, attribute: str, where: str) -> int:
    text = piece.get(attribute, "0")
    try:
        value = int(text)
    except ValueError:
        raise DataFormatError(path, f"{attribute}={text!r} is not an integer", field=f"{where}/{attribute}") from None
    if value < 0:
        raise DataFormatError(path, f"{attribute}={value} is negative", field=f"{where}/{attribute}")
    return value


def _numbers(path: Path, array: ET.Element, field: str, *, integer: bool = False) -> np.ndarray:
    encoding = array.get("format", "ascii")
    if encoding != "ascii":
        raise DataFormatError(path, f"DataArray format={encoding!r}: only ASCII .vtp files are supported", field=field)
    try:
        values = np.array((array.text or "").split(), dtype=float)
    except ValueError as error:
        raise DataFormatError(path, f"bad number ({error})", field=field) from None
    if not integer:
        return values
    if not np.all(values == np.round(values)):
        raise DataFormatError(path, "index is not an integer", field=field)
    return values.astype(np.int64)


def _triangulate(
    path: Path, connectivity: np.ndarray, offsets: np.ndarray, n_points: int, n_polys: int, where: str
) -> np.ndarray:
    """Fan triangles [sum(n_i - 2), 3] of polygons ``connectivity[offsets[i-1]:offsets[i]]``."""
    field = f"{where}/Polys"
    if offsets.size != n_polys:
        raise DataFormatError(path, f"{offsets.size} offsets for NumberOfPolys={n_polys}", field=field)
    starts = np.concatenate([[0], offsets[:-1]])
    sizes = offsets - starts
    if np.any(sizes < 3):
        bad = int(np.flatnonzero(sizes < 3)[0])
        raise DataFormatError(path, f"polygon {bad} has {sizes[bad]} vertices (at least 3 needed)", field=field)
    if offsets[-1] != connectivity.size:
        raise DataFormatError(
            path, f"last offset {offsets[-1]} does not match {connectivity.size} indices", field=field
        )
    if connectivity.size and (connectivity.min() < 0 or connectivity.max() >= n_points):
        raise DataFormatError(path, f"point index out of range [0, {n_points})", field=field)
    fans = sizes - 2
    polygon = np.repeat(np.arange(n_polys), fans)
    step = np.arange(polygon.size) - np.repeat(np.cumsum(fans) - fans, fans) + 1  # 1 .. n_i - 2 within polygon i
    first = starts[polygon]
    return np.stack([connectivity[first], connectivity[first + step], connectivity[first + step + 1]], axis=1)
