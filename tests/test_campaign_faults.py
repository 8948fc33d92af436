"""Campaign building blocks: named sub-streams, the inertia tensor plant, the stall and saturation faults."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from oacli.campaign.sampling import run_seed, sample_run, substream
from oacli.config import ConfigError, config_from_dict, dump_config, load_config
from oacli.config.campaign import CampaignConfig
from oacli.model import quaternion as quat
from oacli.model.rigid_body import propagate
from oacli.sim.full_inertia import TensorPlant
from oacli.sim.sensors import Disturbance, SensorNoise
from oacli.sim.simulator import simulate
from oacli.sim.stall import StalledController
from oacli.types import ControlStep, InertialParams, SolveInfo
from tests.model_helpers import mass_model

ROOT = Path(__file__).resolve().parents[1]


def _base() -> dict:
    return yaml.safe_load(dump_config(load_config(ROOT / "configs" / "doerr2021.yaml")))


def _campaign(**changes) -> CampaignConfig:
    data = {"runs": 10, "seed": 5, "job": "track", "base": "x.yaml",
            "dispersions": {"mass_pct": 2.0, "inertia_pct": [1.0, 2.0, 3.0], "principal_axes_rad": 0.1,
                            "com_offset_m": [0.001, 0.002, 0.003], "actuator_scale_pct": 3.0},
            "faults": {"controller_stall": {"probability": 0.5}, "localisation_jumps": {"probability": 0.3}}}
    data.update(changes)
    return CampaignConfig.model_validate(data)


def test_run_draws_depend_only_on_seed_k_and_their_own_stream():
    base = _base()
    c = _campaign()
    a, b = sample_run(c, base, 3), sample_run(c, copy.deepcopy(base), 3)
    assert a == b
    assert sample_run(c, base, 4)["draws"]["mass_kg"] != a["draws"]["mass_kg"]
    # More runs, or another fault model's probability, leave run 3's other draws as they were.
    other = _campaign(runs=500, faults={"controller_stall": {"probability": 0.5},
                                        "localisation_jumps": {"probability": 1.0}, "actuator_saturation":
                                        {"probability": 1.0}})
    c3 = sample_run(other, base, 3)
    for key in ("mass_kg", "inertia_kgm2", "inertia_tensor_kgm2", "actuator_scale", "controller_stall"):
        assert c3["draws"].get(key) == a["draws"].get(key), key
    assert "actuator_saturation" in c3["draws"]["faults"]
    # The mass is the base times (1 + 2 % × the run's own standard normal).
    z = substream(5, 3, "dispersion/mass").standard_normal()
    assert a["draws"]["mass_kg"] == pytest.approx(base["truth"]["mass_kg"] * (1 + 0.02 * z), rel=1e-15)
    assert a["seed"] == run_seed(5, 3) and 0 <= a["seed"] < 2**31


def test_dispersed_tensor_is_a_rotated_principal_tensor_and_validates():
    base = _base()
    c = _campaign()
    for k in range(5):
        spec = sample_run(c, base, k)
        cfg = config_from_dict(spec["config"])
        tensor = np.asarray(cfg.truth.inertia_tensor_kgm2)
        assert np.allclose(tensor, tensor.T)
        assert np.allclose(np.diag(tensor), cfg.truth.inertia_kgm2, rtol=1e-12)
        z = substream(5, k, "dispersion/inertia").standard_normal(3)
        principal = np.asarray(base["truth"]["inertia_kgm2"]) * (1 + 0.01 * np.array([1.0, 2.0, 3.0]) * z)
        assert np.allclose(np.sort(np.linalg.eigvalsh(tensor)), np.sort(principal), rtol=1e-12)
        assert np.max(np.abs(tensor - np.diag(np.diag(tensor)))) > 0  # products of inertia


@pytest.mark.parametrize(("tensor", "reason"), [
    ([[0.15, 0.01, 0.0], [0.0, 0.14, 0.0], [0.0, 0.0, 0.16]], "symmetric"),
    ([[0.15, 0.2, 0.0], [0.2, 0.14, 0.0], [0.0, 0.0, 0.16]], "positive definite"),
    ([[0.01, 0.0, 0.0], [0.0, 0.01, 0.0], [0.0, 0.0, 0.05]], "triangle"),
])
def test_inertia_tensor_validation_names_field_and_reason(tensor, reason):
    data = _base()
    data["truth"]["inertia_tensor_kgm2"] = tensor
    data["truth"]["inertia_kgm2"] = None
    with pytest.raises(ConfigError) as err:
        config_from_dict(data)
    assert "truth.inertia_tensor_kgm2" in str(err.value) and reason in str(err.value)


def test_inertia_diagonal_must_match_the_tensor():
    data = _base()
    data["truth"]["inertia_tensor_kgm2"] = [[0.15, 0.01, 0.0], [0.01, 0.14, 0.0], [0.0, 0.0, 0.16]]
    data["truth"]["inertia_kgm2"] = [0.15, 0.14, 0.17]
    with pytest.raises(ConfigError, match="diagonal"):
        config_from_dict(data)


def test_tensor_plant_equals_diagonal_plant_and_conserves_angular_momentum():
    x = np.zeros(13)
    x[6:10] = quat.normalize(np.array([0.1, -0.2, 0.3, 0.9]))
    x[10:13] = [0.05, -0.08, 0.12]
    u = np.array([0.1, -0.2, 0.05, 0.01, -0.02, 0.03])
    theta = np.array([9.0, 0.15, 0.14, 0.16])
    diag = TensorPlant(mass_model(9.0).params, np.diag(theta[1:]))
    assert np.allclose(diag.propagate(x, u, theta, 0.016), propagate(x, u, theta, 0.016), rtol=0, atol=1e-15)
    # Torque-free with products of inertia: world-frame angular momentum R J ω and energy are conserved.
    rot = Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix()
    inertia = rot @ np.diag([0.15, 0.14, 0.16]) @ rot.T
    plant = TensorPlant(mass_model(9.0).params, inertia)
    y = x.copy()
    momentum0 = quat.to_rotation_matrix(y[6:10]) @ inertia @ y[10:13]
    energy0 = 0.5 * y[10:13] @ inertia @ y[10:13]
    for _ in range(2000):
        y = plant.propagate(y, np.zeros(6), theta, 0.016)
    momentum = quat.to_rotation_matrix(y[6:10]) @ inertia @ y[10:13]
    assert np.allclose(momentum, momentum0, rtol=0, atol=1e-9 * np.linalg.norm(momentum0) + 1e-12)
    assert 0.5 * y[10:13] @ inertia @ y[10:13] == pytest.approx(energy0, rel=1e-9)
    # ... and the diagonal plant with the same diagonal does not follow it (the products matter).
    z = x.copy()
    for _ in range(2000):
        z = propagate(z, np.zeros(6), np.array([9.0, *np.diag(inertia)]), 0.016)
    assert np.linalg.norm(z[10:13] - y[10:13]) > 1e-3


class _Ramp:
    """Commands u = (t, 0, 0, 0, 0, 0) N."""

    def step(self, t, x_measured):
        return ControlStep(u=np.array([t, 0, 0, 0, 0, 0], float), info=SolveInfo("optimal", True),
                           x_reference=np.zeros(13))


def test_stalled_controller_holds_the_last_command():
    ctrl = StalledController(_Ramp(), start_s=1.0, duration_s=0.5)
    x = np.zeros(13)
    out = [ctrl.step(t, x) for t in (0.0, 0.8, 1.0, 1.2, 1.4, 1.6)]
    assert [o.u[0] for o in out] == [0.0, 0.8, 0.8, 0.8, 0.8, 1.6]
    assert [o.info.status for o in out] == ["optimal", "optimal", "stalled", "stalled", "stalled", "optimal"]


class _Constant:
    def step(self, t, x_measured):
        return ControlStep(u=np.array([0.4, 0, 0, 0, 0, 0.0]), info=SolveInfo("optimal", True),
                           x_reference=np.zeros(13))


def test_saturation_fault_limits_the_delivered_force_only():
    x0 = np.zeros(13)
    x0[9] = 1.0
    limits = np.array([0.5, 0.5, 0.5, 0.05, 0.05, 0.05])
    kw = {"duration_s": 2.0, "control_period_s": 0.2, "plant_period_s": 0.016, "input_limits": limits,
          "sensors": SensorNoise(), "disturbance": Disturbance.none(), "rng": np.random.default_rng(0)}
    truth = InertialParams(10.0, np.array([0.15, 0.14, 0.16]))
    healthy = simulate(_Constant(), x0, truth, **kw)
    faulty = simulate(_Constant(), x0, truth, delivered_limits=0.5 * limits, **kw)
    # v = F t / m: 0.4 N healthy, 0.25 N delivered with half the limit; the recorded input is the command.
    assert healthy.x_true[-1, 3] == pytest.approx(0.4 * 2.0 / 10.0, rel=1e-12)
    assert faulty.x_true[-1, 3] == pytest.approx(0.25 * 2.0 / 10.0, rel=1e-12)
    assert np.array_equal(faulty.u_applied, healthy.u_applied)
