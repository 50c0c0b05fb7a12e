"""XML parsed with expat so that every element knows its source line, for error messages that name it.

Every XML file biomotion reads (.osim models, OpenSim setups, .vtp meshes) goes through this module, which is safe
on untrusted input:

- a ``<!DOCTYPE ...>`` (and with it every ``<!ENTITY ...>`` declaration) is refused with a `DataFormatError`
  naming the file and line: none of the formats needs one, and internal entities are how "billion laughs" and
  quadratic-blowup files expand a few kilobytes into gigabytes; external entities are never resolved;
- element text is gathered by `xml.etree.ElementTree.TreeBuilder`, which joins the pieces expat hands over once
  per element (linear time, however many pieces: character references and long texts arrive in many);
- text and tails follow ElementTree's usual layout (``elem.text`` up to the first child, ``child.tail`` after it),
  so a tree from `parse_tree` writes back as `xml.etree.ElementTree.parse` would have read it.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path
from xml.parsers import expat

from biomotion.errors import DataFormatError


class _Refused(Exception):
    """Raised inside an expat handler to stop the parse; carries the DataFormatError to raise outside."""

    def __init__(self, error: DataFormatError) -> None:
        super().__init__(str(error))
        self.error = error


def _parse(path: str | Path, *, namespaces: bool) -> tuple[ET.Element, dict[int, int]]:
    path = Path(path)
    if path.is_dir():
        raise DataFormatError(path, "is a directory, not an XML file")
    lines: dict[int, int] = {}
    builder = ET.TreeBuilder()
    parser = expat.ParserCreate(namespace_separator="}" if namespaces else None)
    parser.buffer_text = True
    fix = (lambda name: "{" + name if "}" in name else name) if namespaces else (lambda name: name)

    def start(tag: str, attrs: dict[str, str]) -> None:
        elem = builder.start(fix(tag), {fix(key): value for key, value in attrs.items()} if namespaces else attrs)
        lines[id(elem)] = parser.CurrentLineNumber

    def refuse(what: str) -> None:
        raise _Refused(
            DataFormatError(
                path,
                f"{what} declarations are refused (entity expansion is not supported in biomotion's XML formats)",
                line=parser.CurrentLineNumber,
            )
        )

    parser.StartElementHandler = start
    parser.EndElementHandler = lambda tag: builder.end(fix(tag))
    parser.CharacterDataHandler = builder.data
    parser.StartDoctypeDeclHandler = lambda *_: refuse("DOCTYPE")
    parser.EntityDeclHandler = lambda *_: refuse("ENTITY")
    parser.UnparsedEntityDeclHandler = lambda *_: refuse("ENTITY")
    parser.ExternalEntityRefHandler = lambda *_: refuse("external entity")
    try:
        with open(path, "rb") as handle:
            parser.ParseFile(handle)
    except _Refused as refused:
        raise refused.error from None
    except FileNotFoundError:
        raise DataFormatError(path, "no such file") from None
    except OSError as error:
        raise DataFormatError(path, f"cannot read: {error.strerror or error}") from None
    except expat.ExpatError as error:
        if not lines and error.code == expat.errors.codes[expat.errors.XML_ERROR_NO_ELEMENTS]:
            raise DataFormatError(path, "empty file (no XML element)", line=error.lineno) from None
        raise DataFormatError(
            path, f"not well-formed XML: {expat.ErrorString(error.code)}", line=error.lineno
        ) from None
    return builder.close(), lines


def parse_with_lines(path: str | Path) -> tuple[ET.Element, dict[int, int]]:
    """(root element, ``{id(element): line}``); a missing, malformed, empty or DOCTYPE-bearing file raises
    DataFormatError. Names are kept as written (no namespace processing: OpenSim documents use none)."""
    return _parse(path, namespaces=False)


def parse_tree(path: str | Path) -> ET.ElementTree:
    """A safe `xml.etree.ElementTree.parse`: the same tree (namespaced names as ``{uri}local``), with the refusals
    of this module and every failure a DataFormatError naming the file (and line, where the XML is malformed)."""
    return ET.ElementTree(_parse(path, namespaces=True)[0])
