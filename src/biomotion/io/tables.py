"""Subject tables (``.csv``, ``.xlsx``) → `Profile` per subject, through a column mapping per schema.

Schemas known out of the box (``mapping="auto"`` picks by the header):
- ``fukuchi``: the Fukuchi 2017 running data set's ``participantInfo.csv`` (RBDSinfo; one row per original file,
  so rows repeat per subject; ``Experience`` is in months; injury as ``InjuryLoc``/``Diagnostic``/``InjuryOnDate``).
- ``motus``: the movement-screen "Subject Log.xlsx" (Subject ID, Age, Gender, Height (cm), Mass (kg), Level, Sport,
  Injury 1..5).
- ``simple``: ``subject_id, sex, age_years, height_m, mass_kg`` (the SchreiberMoissenet2019 and Hamner2013 tables);
- ``schreiber``: the original Schreiber & Moissenet ``anthropometrics_source.csv`` (gender M/W);
- ``ansur-*``: ANSUR II public release (latin-1, stature in mm, mass in tenths of a kg).
Other tables can pass their own `ColumnMapping`.
"""

from __future__ import annotations

import csv
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from biomotion.errors import DataFormatError
from biomotion.io.atomic import atomic_write
from biomotion.profile import InjuryRecord, Profile

_MISSING = {"", "-", "na", "n/a", "nan", "none", "null"}


def _text(value: Any) -> str | None:
    if value is None:
        return None
    text = str(value).strip()
    return None if text.lower() in _MISSING else text


def _number(value: Any) -> float | None:
    text = _text(value)
    return None if text is None else float(text)


def _sex(value: Any) -> str | None:
    text = _text(value)
    if text is None:
        return None
    first = text[0].upper()
    return {"M": "M", "F": "F", "W": "F"}.get(first)


@dataclass(frozen=True)
class ColumnMapping:
    """How one table schema fills a `Profile`.

    ``fields`` maps a Profile field to (column name, converter); ``constants`` fills fields the whole table shares
    (the Fukuchi set is all runners). ``injuries`` lists groups of columns
    (location, diagnosis, date) — any may be None — one group per injury record. ``subject_id`` turns a row into
    the subject identifier. Unmapped columns go to ``Profile.extra``.
    """

    name: str
    subject_column: str
    fields: Mapping[str, tuple[str, Callable[[Any], Any]]]
    injuries: tuple[tuple[str | None, str | None, str | None], ...] = ()
    subject_id: Callable[[dict[str, Any]], str] | None = None
    row_filter: Callable[[dict[str, Any]], bool] | None = None
    signature: tuple[str, ...] = field(default=())
    constants: Mapping[str, Any] = field(default_factory=dict)


def _fukuchi_id(row: dict[str, Any]) -> str:
    match = re.match(r"(RBDS\d+)", str(row.get("FileName", "")))
    if match:
        return match.group(1)
    return f"RBDS{int(float(row['Subject'])):03d}"


FUKUCHI = ColumnMapping(
    name="fukuchi",
    subject_column="Subject",
    fields={
        "age": ("Age", _number),
        "height": ("Height", lambda v: None if _number(v) is None else _number(v) / 100.0),
        "mass": ("Mass", _number),
        "sex": ("Gender", _sex),
        "dominance": ("Dominance", _text),
        "level": ("Level", lambda v: None if _text(v) is None else _text(v).lower()),
        "experience_years": ("Experience", lambda v: None if _number(v) is None else _number(v) / 12.0),
    },
    injuries=(("InjuryLoc", "Diagnostic", "InjuryOnDate"),),
    subject_id=_fukuchi_id,
    # one row per original file: keep the static trial's row for each subject
    row_filter=lambda row: str(row.get("FileName", "")).endswith("static.c3d"),
    signature=("Subject", "FileName", "Age", "Height", "Mass", "Gender", "InjuryLoc"),
    constants={"sport": "running"},
)

MOTUS = ColumnMapping(
    name="motus",
    subject_column="Subject ID",
    fields={
        "age": ("Age", _number),
        "sex": ("Gender", _sex),
        "height": ("Height (cm)", lambda v: None if _number(v) is None else _number(v) / 100.0),
        "mass": ("Mass (kg)", _number),
        "level": ("Level", lambda v: None if _text(v) is None else _text(v).lower()),
        "sport": ("Sport", lambda v: None if _text(v) is None else _text(v).lower()),
    },
    injuries=tuple((f"Injury {i}", None, None) for i in range(1, 6)),
    signature=("Subject ID", "Age", "Gender", "Height (cm)", "Mass (kg)"),
)

SIMPLE = ColumnMapping(
    name="simple",
    subject_column="subject_id",
    fields={
        "age": ("age_years", _number),
        "sex": ("sex", _sex),
        "height": ("height_m", _number),
        "mass": ("mass_kg", _number),
    },
    signature=("subject_id", "mass_kg"),
)

SCHREIBER_SOURCE = ColumnMapping(
    name="schreiber",
    subject_column="subjectID",
    fields={"age": ("age", _number), "sex": ("gender", _sex), "height": ("height", _number), "mass": ("mass", _number)},
    signature=("subjectID", "gender", "age", "height", "mass", "rightLegLength"),
)


def _ansur_id(row: dict[str, Any]) -> str:
    return str(row.get("subjectid") or row.get("SubjectId"))


def _ansur_mapping(id_column: str) -> ColumnMapping:
    """ANSUR II public release: stature in mm, ``weightkg`` in tenths of a kilogram (anthropometry/SOURCE.md);
    the 93 body measures stay in ``extra`` (mm) for scaling."""
    return ColumnMapping(
        name=f"ansur-{id_column}",
        subject_column=id_column,
        fields={
            "age": ("Age", _number),
            "sex": ("Gender", _sex),
            "height": ("stature", lambda v: None if _number(v) is None else _number(v) / 1000.0),
            "mass": ("weightkg", lambda v: None if _number(v) is None else _number(v) / 10.0),
            "dominance": (
                "WritingPreference",
                lambda v: None if _text(v) is None else {"Right hand": "R", "Left hand": "L"}.get(_text(v)),
            ),
        },
        subject_id=_ansur_id,
        signature=(id_column, "stature", "weightkg", "Gender"),
    )


ANSUR_MALE = _ansur_mapping("subjectid")  # the male file names its id column 'subjectid' ...
ANSUR_FEMALE = _ansur_mapping("SubjectId")  # ... the female file 'SubjectId'

MAPPINGS = {m.name: m for m in (FUKUCHI, MOTUS, SIMPLE, SCHREIBER_SOURCE, ANSUR_MALE, ANSUR_FEMALE)}


def _read_rows(path: Path, *, check_widths: bool = True) -> tuple[list[str], list[dict[str, Any]]]:
    """(header, one record per non-blank row with its ``__line__``); with ``check_widths`` a row with more or fewer
    cells than the header has names is refused (a cell left out would move every later value under the wrong
    column)."""
    if path.is_dir():
        raise DataFormatError(path, "is a directory, not a table")
    if not path.is_file():
        raise DataFormatError(path, "no such file")
    suffix = path.suffix.lower()
    if suffix in (".xlsx", ".xlsm"):
        import openpyxl

        try:
            book = openpyxl.load_workbook(path, read_only=True, data_only=True)
        except Exception as error:  # openpyxl raises many types for a bad workbook
            raise DataFormatError(path, f"not a readable .xlsx workbook ({error})") from None
        sheet = book.worksheets[0]
        rows = [(number, list(r)) for number, r in enumerate(sheet.iter_rows(values_only=True), start=1)]
        book.close()
        rows = [(n, r) for n, r in rows if any(c is not None and str(c).strip() for c in r)]
        if not rows:
            raise DataFormatError(path, "empty sheet")
        header = [str(c).strip() if c is not None else "" for c in rows[0][1]]
        body = rows[1:]
    elif suffix in (".csv", ".tsv", ".txt"):
        try:
            text = path.read_text(encoding="utf-8-sig")
        except UnicodeDecodeError:
            text = path.read_text(encoding="latin-1")
        except OSError as error:
            raise DataFormatError(path, f"cannot read: {error.strerror}") from None
        reader = csv.reader(text.splitlines(), dialect="excel-tab" if suffix == ".tsv" else "excel")
        rows = [(reader.line_num, r) for r in reader if any(c.strip() for c in r)]
        if not rows:
            raise DataFormatError(path, "empty table", line=1)
        header = [c.strip() for c in rows[0][1]]
        body = rows[1:]
    else:
        raise DataFormatError(path, f"unsupported table type {suffix!r} (use .csv or .xlsx)")
    records = []
    for number, row in body:
        if check_widths and len(row) != len(header) and not (suffix in (".xlsx", ".xlsm") and len(row) < len(header)):
            raise DataFormatError(path, f"{len(row)} cells but {len(header)} column names", line=number)
        record = dict(zip(header, row))
        record["__line__"] = number
        records.append(record)
    return header, records


def detect_mapping(header: list[str]) -> ColumnMapping:
    """The known schema whose signature columns are all in ``header``."""
    for mapping in MAPPINGS.values():
        if all(column in header for column in mapping.signature):
            return mapping
    raise DataFormatError(None, "unknown subject-table schema; columns are: " + ", ".join(header))


def table_schema(path: str | Path) -> ColumnMapping | None:
    """The known subject-table schema of the table at ``path`` (.csv, .tsv, .txt, .xlsx), or None when its header
    matches none, or it is not a table."""
    try:
        header, _ = _read_rows(Path(path), check_widths=False)  # the header decides; reading checks the rows
        return detect_mapping(header)
    except DataFormatError:
        return None


def describe_subject_table(path: str | Path, schema: ColumnMapping) -> dict[str, Any]:
    """What a subject table of ``schema`` (`table_schema`) holds, for ``biomotion inspect``: how many subjects,
    and per profile field how many subjects the table gives it (absent values are masked downstream, not
    invented)."""
    profiles = read_subject_table(path, schema)
    fields = ("age", "sex", "height", "mass", "dominance", "sport", "level", "experience_years")
    return {
        "file": str(path),
        "kind": "SubjectTable",
        "schema": schema.name,
        "subjects": len(profiles),
        "first_subjects": list(profiles)[:5],
        "subjects_with_field": {name: sum(getattr(p, name) is not None for p in profiles.values()) for name in fields}
        | {"injuries": sum(bool(p.injuries) for p in profiles.values())},
    }


def read_subject_table(path: str | Path, mapping: str | ColumnMapping = "auto") -> dict[str, Profile]:
    """Read a subject table into ``{subject_id: Profile}`` (SI units; absent values None)."""
    path = Path(path)
    header, records = _read_rows(path)
    if isinstance(mapping, str):
        try:
            mapping = detect_mapping(header) if mapping == "auto" else MAPPINGS[mapping]
        except KeyError:
            raise DataFormatError(path, f"unknown mapping {mapping!r}; known: {', '.join(MAPPINGS)}") from None
        except DataFormatError as error:
            raise DataFormatError(path, str(error).split(": ", 1)[1]) from None
    missing = [c for c in (mapping.subject_column, *(col for col, _ in mapping.fields.values())) if c not in header]
    if missing:
        raise DataFormatError(path, f"columns missing for the {mapping.name!r} schema: {', '.join(missing)}")
    used = {
        mapping.subject_column,
        *(col for col, _ in mapping.fields.values()),
        *(c for group in mapping.injuries for c in group if c),
    }
    profiles: dict[str, Profile] = {}
    for record in records:
        if mapping.row_filter is not None and not mapping.row_filter(record):
            continue
        line = record.pop("__line__")
        subject = mapping.subject_id(record) if mapping.subject_id else _text(record[mapping.subject_column])
        if subject is None:
            raise DataFormatError(path, "row without a subject id", line=line, field=mapping.subject_column)
        subject = str(subject).removesuffix(".0")
        values: dict[str, Any] = dict(mapping.constants)
        for name, (column, convert) in mapping.fields.items():
            try:
                values[name] = convert(record.get(column))
            except (TypeError, ValueError):
                raise DataFormatError(path, f"cannot read {record.get(column)!r}", line=line, field=column) from None
        injuries = []
        for location, diagnosis, date in mapping.injuries:
            parts = [_text(record.get(c)) if c else None for c in (location, diagnosis, date)]
            if any(parts):
                injuries.append(InjuryRecord(*parts))
        extra = {k: v for k, v in record.items() if k not in used and _text(v) is not None}
        try:
            profiles[subject] = Profile(subject_id=subject, injuries=tuple(injuries), extra=extra, **values)
        except ValueError as error:  # a value outside its range (biomotion.profile.RANGES): name its column
            name = getattr(error, "field", None)
            column = mapping.fields[name][0] if name in mapping.fields else name
            raise DataFormatError(path, str(error), line=line, field=column) from None
    if not profiles:
        raise DataFormatError(path, "no subject rows")
    return profiles


def write_csv(path: str | Path, header: list[str], rows: list[list[Any]]) -> Path:
    """Write a CSV table atomically (floats in shortest round-trip form)."""
    with atomic_write(path) as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(header)
        for row in rows:
            writer.writerow([repr(v) if isinstance(v, float) else v for v in row])
    return Path(path)
