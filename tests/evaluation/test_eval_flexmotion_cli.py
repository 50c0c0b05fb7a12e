"""`biomotion eval generation --generator flexmotion|both` (`biomotion.evaluation.flexmotion.eval_flexmotion`):
bad flags are one-line errors (exit 2) before any work is done."""

from __future__ import annotations

from biomotion.cli import main


def test_flexmotion_generation_eval_checks_its_flags(tmp_path, capsys):
    assert main(["eval", "generation", "--generator", "flexmotion"]) == 2
    assert "--json" in capsys.readouterr().err
    report = ["eval", "generation", "--generator", "both", "--json", str(tmp_path / "r.json")]
    assert main([*report, "--data-root", str(tmp_path / "absent")]) == 2
    assert main([*report, "--data-root", str(tmp_path), "--cache", str(tmp_path / "no-cache")]) == 2
    assert "--cache" in capsys.readouterr().err
    assert not (tmp_path / "r.json").exists()
