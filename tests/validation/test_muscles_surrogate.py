"""`surrogate_figures` of `biomotion validate muscles`: held-out agreement of the shipped surrogate."""

from pathlib import Path

from biomotion.validation.muscles import SURROGATE, surrogate_figures


def test_a_data_root_without_the_model_or_sources_is_skipped_by_name(tmp_path):
    skipped: list[str] = []
    figures = surrogate_figures(tmp_path, SURROGATE, skipped)
    assert figures == {"surrogate_r2": None, "surrogate_rmse": None, "surrogate_com_vel_r2": None}
    assert len(skipped) == 1 and "surrogate agreement" in skipped[0]
    skipped.clear()
    assert surrogate_figures(tmp_path, Path(tmp_path / "absent.safetensors"), skipped)["surrogate_r2"] is None
    assert "no surrogate checkpoint" in skipped[0]


def test_every_subject_the_surrogate_never_trained_on_is_scored(tmp_path):
    """A data root holding one runner the project has never seen (RBDS010's 2.5 m/s IK under a new name, linked,
    not copied): the surrogate's training list leaves it in, whatever the hash split says of its name."""
    from biomotion.data.registry import subject_split
    from biomotion.muscles.surrogate import MuscleSurrogate
    from tests.conftest import data_path

    shared = data_path("fukuchi-running")
    root = tmp_path / "root"
    (root / "fukuchi-running/ik/T25").mkdir(parents=True)
    (root / "opensim-models").symlink_to(data_path("opensim-models"))
    (root / "fukuchi-running/ik/T25/RBDS099_T25_ik_simple.mot").symlink_to(shared / "ik/T25/RBDS010_T25_ik_simple.mot")
    assert "fukuchi/RBDS099" not in MuscleSurrogate.training_subjects(SURROGATE)
    assert subject_split("fukuchi", "RBDS099") == "train"  # the hash split alone would have left it out
    skipped: list[str] = []
    figures = surrogate_figures(root, SURROGATE, skipped)
    assert skipped == [] and figures["surrogate_held_out_subjects"] == ["fukuchi/RBDS099"]
    assert figures["surrogate_held_out_clips"] == 1 and 0.0 < figures["surrogate_r2"] <= 1.0
