"""Who moves: a `Profile` from a YAML/JSON profile file or from a row of a subject table.

A profile file is YAML or JSON with `biomotion.profile.Profile` fields (``age``, ``sex``, ``height`` m,
``mass`` kg, ``sport``, ``level``, ``experience_years``, ``injuries`` as a list of ``{location, diagnosis, date}``);
absent fields are masked by the generator. A subject table is any table `biomotion.io.tables` reads (Fukuchi,
Motus, Schreiber, ANSUR II, simple CSV).
"""

from __future__ import annotations

from pathlib import Path

from biomotion.errors import ConfigError, DataFormatError
from biomotion.io.mappings import read_mapping
from biomotion.profile import Profile


def read_profile(path: str | Path) -> Profile:
    """A `Profile` from a YAML or JSON file; errors name the file and the field."""
    path = Path(path)
    data = read_mapping(path, "profile file", "a profile file holds a mapping of fields (age, sex, height, ...)")
    try:
        return Profile.from_dict(data)
    except (TypeError, ValueError) as error:
        raise DataFormatError(path, f"invalid profile: {error}") from None


def subject_profile(table: str | Path, subject_id: str) -> Profile:
    """The row ``subject_id`` of a subject table."""
    from biomotion.io.tables import read_subject_table

    profiles = read_subject_table(table)
    if subject_id not in profiles:
        shown = ", ".join(sorted(profiles)[:10])
        raise ConfigError(f"{table}: no subject {subject_id!r} (the table has {len(profiles)}: {shown} ...)")
    return profiles[subject_id]


def person(profile_file: Path | None, subject_table: Path | None, subject_id: str | None) -> Profile | None:
    """The person the options name: ``--profile FILE``, or ``--subject-table CSV --subject-id ID``, or None."""
    if profile_file is not None and subject_table is not None:
        raise ConfigError("give either --profile or --subject-table/--subject-id, not both")
    if (subject_table is None) != (subject_id is None):
        raise ConfigError("--subject-table and --subject-id go together")
    if profile_file is not None:
        return read_profile(profile_file)
    return subject_profile(subject_table, subject_id) if subject_table is not None else None
