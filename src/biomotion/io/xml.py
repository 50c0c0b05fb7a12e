"""XML parsed with expat so that every element knows its source line, for error messages that name it."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path
from xml.parsers import expat

from biomotion.errors import DataFormatError


def parse_with_lines(path: Path) -> tuple[ET.Element, dict[int, int]]:
    """(root element, ``{id(element): line}``); a missing, malformed or empty file raises DataFormatError."""
    lines: dict[int, int] = {}
    parser = expat.ParserCreate()
    stack: list[ET.Element] = []
    roots: list[ET.Element] = []

    def start(tag: str, attrs: dict[str, str]) -> None:
        elem = ET.Element(tag, attrs) if not stack else ET.SubElement(stack[-1], tag, attrs)
        lines[id(elem)] = parser.CurrentLineNumber
        if not stack:
            roots.append(elem)
        stack.append(elem)

    def text(data: str) -> None:
        if stack:
            stack[-1].text = (stack[-1].text or "") + data

    parser.StartElementHandler = start
    parser.EndElementHandler = lambda tag: stack.pop()
    parser.CharacterDataHandler = text
    try:
        with open(path, "rb") as handle:
            parser.ParseFile(handle)
    except OSError as error:
        raise DataFormatError(path, f"cannot read: {error.strerror}") from None
    except expat.ExpatError as error:
        raise DataFormatError(path, f"not well-formed XML: {expat.ErrorString(error.code)}",
                              line=error.lineno) from None
    if not roots:
        raise DataFormatError(path, "empty XML document", line=1)
    return roots[0], lines
