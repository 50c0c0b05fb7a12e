"""Profile validation: unknown fields named with the closest known one, numbers in their documented ranges,
injuries checked; every refusal is a ProfileError (a ConfigError, and a ValueError) naming the field."""

import math

import pytest
import yaml

from biomotion.errors import ConfigError, DataFormatError, ProfileError
from biomotion.profile import RANGES, InjuryRecord, Profile
from tests.conftest import REPO


def _refused(data) -> ProfileError:
    with pytest.raises(ProfileError) as info:
        Profile.from_dict(data)
    assert isinstance(info.value, ConfigError) and isinstance(info.value, ValueError)
    return info.value


@pytest.mark.parametrize(
    "key, closest",
    [
        ("agee", "age"),
        ("hieght", "height"),
        ("Mass", "mass"),
        ("weight", "mass"),
        ("gender", "sex"),
        ("experiance_years", "experience_years"),
        ("injury", "injuries"),
    ],
)
def test_an_unknown_key_is_named_with_the_closest_field(key, closest):
    error = _refused({"age": 30, key: 1})
    assert error.field == key
    assert f"unknown profile field {key!r} (did you mean {closest!r}?)" in str(error)
    assert "known: subject_id, age, sex, height, mass" in str(error)


def test_several_unknown_keys_are_all_named_and_a_far_one_gets_no_guess():
    error = _refused({"agee": 30, "hieght": 1.7, "zzzz": 0})
    assert "'agee' (did you mean 'age'?), 'hieght' (did you mean 'height'?), 'zzzz';" in str(error)


@pytest.mark.parametrize(
    "name, value",
    [
        ("height", 175),
        ("height", -1.7),
        ("mass", -70.0),
        ("mass", 0.5),
        ("age", -1),
        ("age", 200),
        ("age", math.nan),
        ("height", math.inf),
        ("experience_years", 150),
        ("experience_years", -2),
    ],
)
def test_numbers_outside_their_documented_range_are_refused(name, value):
    error = _refused({name: value})
    low, high, unit = RANGES[name]
    assert error.field == name and f"{name}={value} is outside [{low:g}, {high:g}] {unit}" in str(error)


def test_height_in_centimetres_gets_a_hint_and_types_are_checked():
    assert "in metres, 1.75 for 175 cm" in str(_refused({"height": 175}))
    for name, value in (("age", "fifty"), ("mass", True), ("height", [1.7])):
        error = _refused({name: value})
        assert error.field == name and f"{name} must be a number" in str(error)
    assert _refused({"sex": "female"}).field == "sex"


def test_injuries_and_extra_are_checked():
    error = _refused({"injuries": [{"location": "knee", "diagnoses": "ACL"}]})
    assert error.field == "injuries[0].diagnoses" and "(did you mean 'diagnosis'?)" in str(error)
    assert _refused({"injuries": "knee"}).field == "injuries"
    assert _refused({"injuries": ["knee"]}).field == "injuries[0]"
    assert _refused({"extra": ["notes"]}).field == "extra"


def test_valid_profiles_round_trip_and_the_example_reads():
    profile = Profile(
        subject_id="x",
        age=52,
        sex="M",
        height=1.76,
        mass=74.0,
        experience_years=15,
        injuries=(InjuryRecord("Left knee", "ACL"),),
        extra={"shoe": "neutral"},
    )
    assert Profile.from_dict(profile.to_dict()) == profile
    for name, (low, high, _) in RANGES.items():  # the bounds themselves are valid
        assert getattr(Profile.from_dict({name: low}), name) == low
        assert getattr(Profile.from_dict({name: high}), name) == high
    example = REPO / "examples" / "runner_52_acl.yaml"
    if example.exists():
        loaded = Profile.from_dict(yaml.safe_load(example.read_text()))
        assert loaded.age == 52 and loaded.injuries[0].diagnosis == "ACL reconstruction"


def test_a_profile_file_with_a_typo_names_the_file_and_the_field(tmp_path):
    profiles = pytest.importorskip("biomotion.io.profiles")
    path = tmp_path / "person.yaml"
    path.write_text("agee: 30\nheight: 1.7\n")
    with pytest.raises(DataFormatError) as info:
        profiles.read_profile(path)
    assert str(path) in str(info.value) and "'agee' (did you mean 'age'?)" in str(info.value)


def test_a_subject_table_row_out_of_range_names_line_and_column(tmp_path):
    from biomotion.io.tables import read_subject_table

    table = tmp_path / "people.csv"
    table.write_text("subject_id,sex,age_years,height_m,mass_kg\ns1,F,52,1.68,61\ns2,M,40,180,80\n")
    with pytest.raises(DataFormatError, match="height=180.0 is outside") as info:
        read_subject_table(table)
    assert str(info.value).startswith(f"{table}:3: field 'height_m': ")


def _alias_bomb(leaf: str) -> str:
    """Nine levels of ten YAML aliases: a billion leaves once expanded, built by the parser in microseconds."""
    value = leaf
    for k in range(9):
        value = f"[&l{k} {value}" + f", *l{k}" * 9 + "]"
    return value


@pytest.mark.parametrize(
    "field, text",
    [
        ("injuries", "injuries: " + _alias_bomb("{location: knee}")),
        ("extra", "extra: {shoes: " + _alias_bomb("a") + "}"),
        ("sport", "sport: " + _alias_bomb("a")),
    ],
)
def test_a_yaml_alias_bomb_is_refused_at_once_with_a_short_message(tmp_path, field, text):
    """The message used the value's full repr, a billion items (bad-input corpus case profile-yaml-alias-bomb hung
    past its 60 s); a text field or an extra value held anything YAML built, later dumped into metrics.json."""
    from biomotion.io.profiles import read_profile

    path = tmp_path / "bomb.yaml"
    path.write_text(f"age: 30\n{text}\n")
    with pytest.raises(DataFormatError, match=field) as info:
        read_profile(path)
    assert len(str(info.value)) < 400


def test_numbers_and_dates_in_text_fields_become_text():
    """YAML reads ``date: 2015-03-01`` as a date and ``subject_id: 12`` as a number: kept as their text."""
    profile = Profile.from_dict(
        yaml.safe_load("subject_id: 12\nlevel: 3\ninjuries: [{location: knee, date: 2015-03-01}]\nextra: {a: [1, x]}")
    )
    assert (profile.subject_id, profile.level, profile.injuries[0].date) == ("12", "3", "2015-03-01")
    with pytest.raises(ProfileError, match="sport must be text, got \\['running'\\]"):
        Profile(sport=["running"])
    with pytest.raises(ProfileError, match="extra.shoes must be a value or a list of values"):
        Profile(extra={"shoes": {"left": 1}})
