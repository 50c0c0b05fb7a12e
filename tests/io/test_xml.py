"""The XML layer every reader shares: DOCTYPE and entity declarations refused (billion laughs, quadratic blowup,
external entities), element text gathered in linear time, the same tree as ElementTree, errors naming the file."""

import time
import xml.etree.ElementTree as ET

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from biomotion.errors import DataFormatError
from biomotion.io.osim import read_marker_set, read_osim
from biomotion.io.setup import read_ik_setup
from biomotion.io.vtp import read_vtp
from biomotion.io.xml import parse_tree, parse_with_lines

LAUGHS = (
    '<?xml version="1.0"?>\n<!DOCTYPE lolz [\n <!ENTITY lol "lol">\n'
    + "".join(f' <!ENTITY lol{i} "' + (f"&lol{i - 1};" if i > 1 else "&lol;") * 10 + '">\n' for i in range(1, 10))
    + ']>\n<OpenSimDocument Version="40000"><Model name="m">&lol9;</Model></OpenSimDocument>\n'
)
QUADRATIC = (
    '<?xml version="1.0"?>\n<!DOCTYPE r [<!ENTITY a "' + "x" * 50_000 + '">]>\n'
    '<OpenSimDocument Version="40000"><Model name="m">' + "&a;" * 50_000 + "</Model></OpenSimDocument>\n"
)
EXTERNAL = (
    '<?xml version="1.0"?>\n<!DOCTYPE r [<!ENTITY secret SYSTEM "file:///etc/passwd">]>\n'
    '<OpenSimDocument Version="40000"><Model name="&secret;"/></OpenSimDocument>\n'
)
READERS = {
    "parse_with_lines": parse_with_lines,
    "parse_tree": parse_tree,
    "read_osim": read_osim,
    "read_marker_set": read_marker_set,
    "read_ik_setup": read_ik_setup,
    "read_vtp": read_vtp,
}


@pytest.mark.parametrize("reader", list(READERS))
@pytest.mark.parametrize("name, text", [("laughs", LAUGHS), ("quadratic", QUADRATIC), ("external", EXTERNAL)])
def test_doctype_and_entities_are_refused_at_once(tmp_path, reader, name, text):
    path = tmp_path / f"{name}.xml"
    path.write_text(text)
    start = time.perf_counter()
    with pytest.raises(DataFormatError, match="DOCTYPE declarations are refused") as info:
        READERS[reader](path)
    assert time.perf_counter() - start < 0.5
    assert str(info.value).startswith(f"{path}:2: ") and info.value.line == 2


def test_many_text_pieces_are_joined_in_linear_time(tmp_path):
    """Character references arrive from expat as separate pieces: 200 000 of them in one element."""
    path = tmp_path / "pieces.vtp"
    path.write_text("<VTKFile><x>" + "1&#32;" * 200_000 + "</x></VTKFile>")
    start = time.perf_counter()
    root, lines = parse_with_lines(path)
    assert time.perf_counter() - start < 0.5
    assert root[0].text == "1 " * 200_000 and lines[id(root[0])] == 1


@pytest.mark.parametrize(
    "content, message, line",
    [("", "empty file", 1), ("  \n\n", "empty file", 3), ("<a>\n<b>\n</a>\n", "not well-formed XML", 3)],
)
def test_empty_and_malformed_files_name_the_file_and_line(tmp_path, content, message, line):
    path = tmp_path / "bad.osim"
    path.write_text(content)
    for reader in (parse_with_lines, parse_tree, read_osim):
        with pytest.raises(DataFormatError, match=message) as info:
            reader(path)
        assert str(info.value).startswith(f"{path}:{line}: ")


def test_directories_and_missing_files(tmp_path):
    for reader in (parse_with_lines, parse_tree, read_osim, read_vtp):
        with pytest.raises(DataFormatError, match="is a directory") as info:
            reader(tmp_path)
        assert str(info.value).startswith(f"{tmp_path}: ")
        with pytest.raises(DataFormatError, match="no such file"):
            reader(tmp_path / "absent.osim")


names = st.sampled_from(["a", "b", "Body", "objects", "p:q"])
texts = st.text(alphabet=st.sampled_from("xy 1.5\n\t<&>\"'"), max_size=8)


@st.composite
def documents(draw, depth=0):
    elem = ET.Element(
        draw(names).replace("p:", ""),
        {k: draw(texts) for k in draw(st.lists(st.sampled_from(["name", "file", "Version"]), max_size=2, unique=True))},
    )
    elem.text = draw(texts) or None
    if depth < 3:
        for _ in range(draw(st.integers(0, 3))):
            child = draw(documents(depth + 1))
            child.tail = draw(texts) or None
            elem.append(child)
    return elem


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(document=documents())
def test_property_same_tree_as_elementtree(tmp_path, document):
    path = tmp_path / "doc.xml"
    path.write_bytes(ET.tostring(document, encoding="utf-8", xml_declaration=True))
    expected = ET.tostring(ET.parse(path).getroot())
    assert ET.tostring(parse_tree(path).getroot()) == expected
    assert ET.tostring(parse_with_lines(path)[0]) == expected
