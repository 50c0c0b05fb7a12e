"""Mass matrix, bias forces and inverse dynamics against OpenSim 4.6's SimbodyMatterSubsystem.calcM and
InverseDynamicsSolver: random states, the gait2392 subject01 walk (stored IK + measured GRF), external loads,
internal consistency (CRBA vs RNEA, power balance) and autograd."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from biomotion.body.dynamics import ExternalLoad, bias_forces, inverse_dynamics, mass_matrix
from biomotion.body.model import BodyModel
from biomotion.errors import ModelError
from tests.body.oracle import Oracle, osim, random_poses
from tests.conftest import data_path

ID_TOLERANCE = 1e-4  # N·m or N; measured errors are about 1e-12
MODELS = (
    "opensim-models/Models/Rajagopal/Rajagopal2016.osim",
    "opensim-models/Models/Rajagopal/RajagopalLaiUhlrich2023.osim",
    "opensim-models/Pipelines/Gait2392_Simbody/OutputReference/subject01_simbody.osim",
    "fukuchi-running/RBDS001/RBDS001_simple.osim",
    "fukuchi-running/generic-models/Uhlrich2022_LowerLimb_Fukuchi2017.osim",
    "opencap/Subject4/Models/optimized_scale_and_markers.osim",
    "Hamner2013/subject01/subject01_adjusted_scaled.osim",
    "SchreiberMoissenet2019/2014001/2014001_scaledModelAdjusted.osim",
)
GAIT = "opensim-models/Pipelines/Gait2392_Simbody/"


def _random_state(model: BodyModel, seed: int, count: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    rng = np.random.default_rng(seed)
    q = random_poses(model, rng, count)
    return torch.tensor(q), torch.tensor(rng.normal(size=q.shape) * 2.0), torch.tensor(rng.normal(size=q.shape) * 5.0)


@pytest.mark.parametrize("relative", MODELS)
def test_inverse_dynamics_and_mass_matrix_match_opensim(relative: str) -> None:
    path = data_path(relative)
    model, oracle = BodyModel.from_osim(path), Oracle(path)
    q, qd, qdd = _random_state(model, 5, 3)
    tau = inverse_dynamics(model, q, qd, qdd)
    matrix = mass_matrix(model, q)
    for k in range(3):
        oracle.set(q[k].numpy(), qd[k].numpy())
        assert np.abs(tau[k].numpy() - oracle.inverse_dynamics(qdd[k].numpy())).max() <= ID_TOLERANCE
        assert np.abs(matrix[k].numpy() - oracle.mass_matrix()).max() <= 1e-9


def _external_force(storage, prefix: str, body: str):
    force = osim.ExternalForce(
        storage,
        f"{prefix}ground_force_v",
        f"{prefix}ground_force_p",
        f"{prefix}ground_torque_",
        body,
        "ground",
        "ground",
    )
    force.setName(f"{body}_grf")
    return force


def test_walk_with_ground_reactions_matches_opensim() -> None:
    """Stored subject01 IK (degrees) with central-difference rates, and the measured GRF of both feet applied as
    in subject01_walk1_grf.xml (ground_force_* on calcn_r, 1_ground_force_* on calcn_l), at frames where the
    60 Hz IK and 600 Hz GRF samples coincide."""
    model_path = data_path(GAIT + "OutputReference/subject01_simbody.osim")
    ik = osim.TimeSeriesTable(str(data_path(GAIT + "subject01_walk1_ik.mot")))
    grf_path = data_path(GAIT + "subject01_walk1_grf.mot")
    storage = osim.Storage(str(grf_path))
    oracle = Oracle(model_path, (_external_force(storage, "", "calcn_r"), _external_force(storage, "1_", "calcn_l")))
    model = BodyModel.from_osim(model_path)
    times = np.array(ik.getIndependentColumn())
    columns = list(ik.getColumnLabels())
    q = np.stack([ik.getDependentColumn(name).to_numpy() for name in model.coordinate_names], -1)
    rotational = np.array([t != "translational" for t in model.motion_types])
    q[:, rotational] = np.radians(q[:, rotational])
    dt = times[1] - times[0]
    qd, qdd = np.gradient(q, dt, axis=0), np.gradient(np.gradient(q, dt, axis=0), dt, axis=0)
    grf = osim.TimeSeriesTable(str(grf_path))
    grf_times = np.array(grf.getIndependentColumn())
    frames = [k for k in range(5, 61, 5)]  # 0.58-1.5 s: both single and double support
    rows = [int(np.argmin(np.abs(grf_times - times[k]))) for k in frames]
    assert set(columns) == set(model.coordinate_names)

    def column(name: str) -> torch.Tensor:
        return torch.tensor(grf.getDependentColumn(name).to_numpy()[rows])

    def load(prefix: str, body: str) -> ExternalLoad:
        vec = lambda stem: torch.stack([column(f"{prefix}{stem}{axis}") for axis in "xyz"], -1)  # noqa: E731
        return ExternalLoad(body, vec("ground_force_v"), vec("ground_force_p"), vec("ground_torque_"))

    loads = [load("", "calcn_r"), load("1_", "calcn_l")]
    tau = inverse_dynamics(model, torch.tensor(q[frames]), torch.tensor(qd[frames]), torch.tensor(qdd[frames]), loads)
    assert float(loads[0].force[:, 1].max()) > 500.0  # the right foot is loaded in some of these frames
    for i, k in enumerate(frames):
        oracle.set(q[k], qd[k], time=float(grf_times[rows[i]]))
        assert np.abs(tau[i].numpy() - oracle.inverse_dynamics(qdd[k])).max() <= ID_TOLERANCE


def test_random_external_loads_match_opensim() -> None:
    path = data_path("opensim-models/Models/Rajagopal/Rajagopal2016.osim")
    model = BodyModel.from_osim(path)
    rng = np.random.default_rng(6)
    storage = osim.Storage()
    labels = osim.ArrayStr()
    for label in ["time"] + [
        f"{p}{s}{a}" for p in ("", "1_") for s in ("ground_force_v", "ground_force_p", "ground_torque_") for a in "xyz"
    ]:
        labels.append(label)
    storage.setColumnLabels(labels)
    values = np.concatenate(
        [
            rng.normal(size=3) * 400,
            rng.normal(size=3),
            rng.normal(size=3) * 20,
            rng.normal(size=3) * 100,
            rng.normal(size=3),
            rng.normal(size=3) * 5,
        ]
    )
    for time in (0.0, 1.0):
        row = osim.Vector(18, 0.0)
        for i, v in enumerate(values):
            row.set(i, float(v))
        storage.append(time, row)
    oracle = Oracle(path, (_external_force(storage, "", "calcn_r"), _external_force(storage, "1_", "hand_l")))
    q, qd, qdd = _random_state(model, 7, 2)
    v = torch.tensor(values)
    loads = [ExternalLoad("calcn_r", v[0:3], v[3:6], v[6:9]), ExternalLoad("hand_l", v[9:12], v[12:15], v[15:18])]
    tau = inverse_dynamics(model, q, qd, qdd, loads)
    for k in range(2):
        oracle.set(q[k].numpy(), qd[k].numpy(), time=0.5)
        assert np.abs(tau[k].numpy() - oracle.inverse_dynamics(qdd[k].numpy())).max() <= ID_TOLERANCE


def test_crba_and_rnea_agree() -> None:
    model = BodyModel.from_osim(data_path(MODELS[0]))
    q, qd, qdd = _random_state(model, 8, 4)
    tau = inverse_dynamics(model, q, qd, qdd)
    assert torch.allclose(
        tau, (mass_matrix(model, q) @ qdd[..., None]).squeeze(-1) + bias_forces(model, q, qd), atol=1e-9, rtol=0
    )
    unit = inverse_dynamics(
        model, q, torch.zeros_like(q), torch.eye(model.n_q, dtype=q.dtype)[:, None, :].expand(-1, 4, -1), gravity=False
    )
    assert torch.allclose(unit.permute(1, 2, 0), mass_matrix(model, q), atol=1e-9, rtol=0)


def test_exact_velocity_terms_conserve_power() -> None:
    """Without gravity and loads, qd . tau = d/dt (1/2 qd' M qd) holds for the exact velocity terms; OpenSim's
    (hdot="opensim") differ from them only in the Rajagopal walker knees, by ~1e-4 N·m at these speeds."""
    model = BodyModel.from_osim(data_path(MODELS[0]))
    q, qd, qdd = _random_state(model, 9, 3)
    tau = inverse_dynamics(model, q, qd, qdd, gravity=False, hdot="exact")
    _, m_dot = torch.func.jvp(lambda x: mass_matrix(model, x), (q,), (qd,))
    power = (qd[..., None, :] @ mass_matrix(model, q) @ qdd[..., None]).squeeze((-1, -2)) + 0.5 * (
        qd[..., None, :] @ m_dot @ qd[..., None]
    ).squeeze((-1, -2))
    assert torch.allclose((qd * tau).sum(-1), power, atol=1e-9, rtol=0)
    opensim_style = inverse_dynamics(model, q, qd, qdd, gravity=False)
    difference = (opensim_style - tau).abs()
    knees = [model.coordinate_index(n) for n in ("knee_angle_r", "knee_angle_l")]
    assert 1e-7 < float(difference.max()) < 1e-1
    elsewhere = [
        i
        for i, name in enumerate(model.coordinate_names)  # joints outside the knees' chains
        if name.startswith(("lumbar", "arm_", "elbow", "pro_sup", "wrist")) or name.endswith("_beta")
    ]
    assert float(difference[..., elsewhere].max()) <= 1e-10
    assert float(difference[..., knees].max()) > 0.0
    with pytest.raises(ModelError, match="hdot"):
        inverse_dynamics(model, q, qd, qdd, hdot="simbody")


def test_inverse_dynamics_gradcheck() -> None:
    model = BodyModel.from_osim(data_path(MODELS[3]))
    q, qd, qdd = (x.requires_grad_() for x in _random_state(model, 10, 1))
    assert torch.autograd.gradcheck(lambda a, b, c: inverse_dynamics(model, a, b, c), (q, qd, qdd))


def test_inverse_dynamics_directional_derivative_through_splines() -> None:
    """Autograd through the Rajagopal knee splines against a central difference along a random direction."""
    model = BodyModel.from_osim(data_path(MODELS[0]))
    q, qd, qdd = _random_state(model, 11, 2)
    direction = torch.tensor(np.random.default_rng(12).normal(size=q.shape))
    _, derivative = torch.func.jvp(lambda x: inverse_dynamics(model, x, qd, qdd), (q,), (direction,))
    h = 1e-6
    numeric = (
        inverse_dynamics(model, q + h * direction, qd, qdd) - inverse_dynamics(model, q - h * direction, qd, qdd)
    ) / (2 * h)
    assert (derivative - numeric).abs().max() <= 1e-5 * max(1.0, float(numeric.abs().max()))
