"""Shipped muscle path functions: self-consistency, persistence, and moment arms against OpenSim 4.6."""

import json

import pytest
import torch

from biomotion.errors import DataFormatError, ModelError
from biomotion.muscles.geometry import MusclePaths, PathGroup, basis, shipped_paths
from tests.conftest import data_path

RAJAGOPAL = "opensim-models/Models/Rajagopal/Rajagopal2016.osim"
GAIT_MODEL = "opensim-models/Pipelines/Gait2392_Simbody/OutputReference/subject01_simbody.osim"


def _poses(paths: MusclePaths, n: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    low, high = paths.ranges[:, 0].nan_to_num(0.0), paths.ranges[:, 1].nan_to_num(0.0)
    return low + (high - low) * torch.rand(n, paths.n_q, generator=g, dtype=torch.float64)


@pytest.mark.parametrize("name, muscles", [("rajagopal2016", 80), ("gait2392_subject01", 92)])
def test_moment_arms_are_minus_the_length_gradient(name, muscles):
    paths = shipped_paths(name)
    assert paths.n_muscles == muscles
    q = _poses(paths, 16).requires_grad_(True)
    lengths, arms = paths.lengths_and_moment_arms(q)
    some = range(0, paths.n_muscles, 7)
    gradient = torch.stack([torch.autograd.grad(lengths[:, m].sum(), q, retain_graph=True)[0] for m in some], 1)
    torch.testing.assert_close(arms[:, list(some)], -gradient, rtol=0, atol=1e-12)
    assert bool(((lengths > 0.02) & (lengths < 1.0)).all())  # musculotendon lengths of a human leg, in metres


def test_rajagopal_spans():
    paths = shipped_paths("rajagopal2016")
    spans = paths.spanned()
    row = paths.muscle_names.index
    col = paths.coordinate_names.index
    assert bool(spans[row("recfem_r"), col("knee_angle_r")]) and bool(spans[row("recfem_r"), col("hip_flexion_r")])
    assert not bool(spans[row("soleus_r"), col("knee_angle_r")])
    assert not bool(spans[:, col("pelvis_tx")].any()) and not bool(spans[:, col("knee_angle_r_beta")].any())


def test_save_load_round_trip_and_bad_files(tmp_path):
    paths = shipped_paths("gait2392_subject01")
    paths.save(tmp_path / "p.safetensors")
    again = MusclePaths.load(tmp_path / "p.safetensors")
    q = _poses(paths, 4)
    torch.testing.assert_close(again.lengths(q), paths.lengths(q), rtol=0, atol=0)
    (tmp_path / "junk.safetensors").write_bytes(b"not a tensor file")
    with pytest.raises(DataFormatError, match="junk.safetensors"):
        MusclePaths.load(tmp_path / "junk.safetensors")
    with pytest.raises(ModelError):
        paths.lengths(torch.zeros(3, 5, dtype=torch.float64))
    with pytest.raises(ModelError, match="available"):
        shipped_paths("nope")


@pytest.mark.parametrize(
    "name, model, muscles",
    [
        (
            "rajagopal2016",
            RAJAGOPAL,
            [
                "glmed1_r",
                "semiten_r",
                "recfem_r",
                "bfsh_l",
                "tibant_r",
                "iliacus_l",
                "gasmed_r",
                "glmax1_r",
                "glmax2_l",
            ],
        ),
        (
            "gait2392_subject01",
            GAIT_MODEL,
            ["glut_max1_r", "med_gas_r", "rect_fem_r", "vas_int_l", "ercspn_r", "iliacus_r", "psoas_l"],
        ),
    ],
)
def test_moment_arms_match_opensim(name, model, muscles):
    pytest.importorskip("opensim")
    from biomotion.validation.muscles import moment_arm_errors

    errors = moment_arm_errors(shipped_paths(name), data_path(model), poses=80, seed=7, muscles=muscles)
    assert {m for m, _ in errors} == set(muscles)  # every muscle has at least one non-zero moment arm
    worst = max(errors, key=errors.get)
    assert errors[worst] <= 2e-3, f"{worst}: {errors[worst] * 1000:.2f} mm"
    # gasmed: OpenSim's computeMomentArm (the target) differs from -dL/dq of its length under two wraps;
    # glmax1-2 and the gait2392 iliacus/psoas jump between path configurations and are piecewise (below)


def test_jumping_paths_are_piecewise():
    """Muscles whose OpenSim path jumps (gait2392's conditional via point at the pelvic brim; Rajagopal's
    quadrant-limited gluteus maximus wrap cylinders) get one polynomial per configuration and a gate."""
    for name, muscles in (
        ("gait2392_subject01", ["iliacus_r", "psoas_l"]),
        ("rajagopal2016", ["glmax1_r", "glmax2_l"]),
    ):
        paths = shipped_paths(name)
        for muscle in muscles:
            m = paths.muscle_names.index(muscle)
            group = next(g for g in paths.groups if m in g.muscles.tolist())
            assert group.gates is not None and int((group.muscles == m).sum()) >= 2
            assert len(paths.info["muscles"][muscle]["pieces"]) == int((group.muscles == m).sum())


def _two_piece_paths() -> MusclePaths:
    """Muscle 0: L = 0.3 + 0.02 x where x < 0.25 and 0.31 - 0.01 x elsewhere (gate scores 0 and 4x - 1);
    muscle 1: one polynomial 0.2 + 0.01 x^2 in the same group; x = q / 2 on q in [-2, 2]."""
    exponents = torch.tensor([[0], [1], [2]])
    coefficients = torch.tensor(
        [[0.3, 0.31, 0.2 + 0.005], [0.02, -0.01, 0.0], [0.0, 0.0, 0.005]], dtype=torch.float64
    )  # T_2 = 2x^2 - 1, so 0.01 x^2 = 0.005 T_2 + 0.005
    gates = torch.tensor([[0.0, -1.0, 0.0], [0.0, 4.0, 0.0], [0.0, 0.0, 0.0]], dtype=torch.float64)
    group = PathGroup(
        torch.tensor([0]),
        torch.tensor([0.0], dtype=torch.float64),
        torch.tensor([2.0], dtype=torch.float64),
        exponents,
        coefficients,
        torch.tensor([0, 0, 1]),
        gates,
    )
    return MusclePaths("toy", ("a", "b"), ("q",), (group,), torch.tensor([[-2.0, 2.0]], dtype=torch.float64), {})


def test_piecewise_paths_pick_the_gated_piece_and_stay_consistent(tmp_path):
    paths = _two_piece_paths()
    q = torch.linspace(-1.99, 1.99, 41, dtype=torch.float64)[:, None]
    x = q[:, 0] / 2
    lengths, arms = paths.lengths_and_moment_arms(q)
    first = x < 0.25
    torch.testing.assert_close(lengths[:, 0], torch.where(first, 0.3 + 0.02 * x, 0.31 - 0.01 * x))
    torch.testing.assert_close(arms[:, 0, 0], torch.where(first, -0.01, 0.005).to(torch.float64))  # -dL/dq
    torch.testing.assert_close(lengths[:, 1], 0.2 + 0.01 * x**2)
    q = q.clone().requires_grad_(True)
    lengths, arms = paths.lengths_and_moment_arms(q)
    gradient = torch.autograd.grad(lengths[:, 0].sum(), q)[0]
    torch.testing.assert_close(arms[:, 0], -gradient, rtol=0, atol=1e-15)
    paths.save(tmp_path / "toy.safetensors")
    again = MusclePaths.load(tmp_path / "toy.safetensors")
    torch.testing.assert_close(again.lengths(q.detach()), paths.lengths(q.detach()), rtol=0, atol=0)
    assert again.to(torch.float32).lengths(q.detach().float()).dtype == torch.float32


def test_format_1_files_still_load(tmp_path):
    from safetensors import safe_open
    from safetensors.torch import save_file

    paths = shipped_paths("gait2392_subject01")
    ungated = MusclePaths(
        paths.model,
        paths.muscle_names,
        paths.coordinate_names,
        tuple(g for g in paths.groups if g.gates is None),
        paths.ranges,
        {},
    )
    ungated.save(tmp_path / "p.safetensors")
    with safe_open(str(tmp_path / "p.safetensors"), framework="pt") as handle:
        meta, tensors = handle.metadata(), {k: handle.get_tensor(k) for k in handle.keys()}
    save_file(tensors, str(tmp_path / "old.safetensors"), metadata={**meta, "format": "biomotion.muscle_paths/1"})
    q = _poses(paths, 4)
    torch.testing.assert_close(MusclePaths.load(tmp_path / "old.safetensors").lengths(q), ungated.lengths(q))
    assert json.loads(meta["muscles"]) == list(paths.muscle_names)


def test_basis_derivatives_match_autograd():
    exponents = torch.tensor([[0, 0, 0], [1, 0, 2], [3, 1, 0], [2, 2, 2], [0, 5, 1]])
    x = (torch.rand(7, 3, dtype=torch.float64) * 2 - 1).requires_grad_(True)
    values, derivatives = basis(x, exponents)
    for t in range(len(exponents)):
        gradient = torch.autograd.grad(values[:, t].sum(), x, retain_graph=True)[0]
        torch.testing.assert_close(derivatives[:, t], gradient)
