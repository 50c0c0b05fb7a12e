"""`surrogate_figures` of `biomotion validate muscles`: held-out agreement of the shipped surrogate."""

from pathlib import Path

from biomotion.muscles.validation import SURROGATE, surrogate_figures


def test_a_data_root_without_the_model_or_sources_is_skipped_by_name(tmp_path):
    skipped: list[str] = []
    figures = surrogate_figures(tmp_path, SURROGATE, skipped)
    assert figures == {"surrogate_r2": None, "surrogate_rmse": None, "surrogate_com_vel_r2": None}
    assert len(skipped) == 1 and "surrogate agreement" in skipped[0]
    skipped.clear()
    assert surrogate_figures(tmp_path, Path(tmp_path / "absent.safetensors"), skipped)["surrogate_r2"] is None
    assert "no surrogate checkpoint" in skipped[0]
