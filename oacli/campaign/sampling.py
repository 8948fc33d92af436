"""Each run's config: the base config with its dispersions and faults drawn from named sub-streams.

Run ``k`` of a campaign with seed ``s`` draws everything from ``numpy.random.SeedSequence(s, spawn_key=(k, h))``
where ``h`` is the CRC-32 of a name: one sub-stream per dispersion (``dispersion/mass`` ...) and per fault
(``fault/controller_stall`` ...), plus ``seed`` for the run's own config seed (the seed of its stages' noise). A
run therefore depends only on (campaign seed, k, the resolved campaign config, oacli version), and adding a fault
model, or changing one, leaves every other draw as it was (the same design as :mod:`oacli.sim.substreams`).
"""

from __future__ import annotations

import copy
import zlib
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from oacli.campaign.cells import cell_and_replicate
from oacli.config.campaign import CampaignConfig
from oacli.config.mission import deep_merge

SENSOR_STD_KEYS = ("position_std_m", "velocity_std_mps", "attitude_std_rad", "angular_velocity_std_radps")
ACTUATOR_SCALE_BOUNDS = (0.5, 1.5)
"""truth.actuator_scale must stay in this range (oacli.config.robot)."""


def substream(seed: int, k: int, name: str) -> np.random.Generator:
    """The generator of sub-stream ``name`` of run ``k``.

    Parameters
    ----------
    seed : int
        Campaign seed.
    k : int
        Run index.
    name : str
        Sub-stream name.

    Returns
    -------
    numpy.random.Generator
    """
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(int(k), zlib.crc32(name.encode()))))


def run_seed(seed: int, k: int) -> int:
    """The config seed of run ``k`` (its stages' own noise streams derive from it), in [0, 2³¹).

    Parameters
    ----------
    seed : int
        Campaign seed.
    k : int
        Run index.

    Returns
    -------
    int
    """
    state = np.random.SeedSequence(int(seed), spawn_key=(int(k), zlib.crc32(b"seed"))).generate_state(1)
    return int(state[0] % (2**31))


def _plant_keys(job: str) -> tuple[list[str], list[str]]:
    """Where the dispersed plant's mass and inertias live in the config (the grasped plant of a mission)."""
    if job == "mission":
        return ["mission", "grasped", "mass_kg"], ["mission", "grasped", "inertia_kgm2"]
    return ["truth", "mass_kg"], ["truth", "inertia_kgm2"]


def _get(data: dict[str, Any], keys: list[str]) -> Any:
    node: Any = data
    for key in keys:
        node = node[key]
    return node


def _set(data: dict[str, Any], keys: list[str], value: Any) -> None:
    node = data
    for key in keys[:-1]:
        node = node.setdefault(key, {})
    node[keys[-1]] = value


def _tensor_sets(job: str, tensor: np.ndarray) -> dict[str, Any]:
    rows = [[float(v) for v in row] for row in tensor]
    if job == "mission":  # the payload's tensor acts after the grasp (segments 2 and 3); its diagonal is grasped's
        truth = {"truth": {"inertia_tensor_kgm2": rows, "inertia_kgm2": [float(v) for v in np.diag(tensor)]}}
        return {"mission": {"segments": {"segment-2": truth, "segment-3": copy.deepcopy(truth)}}}
    return {"truth": {"inertia_tensor_kgm2": rows}}


MAX_INERTIA_DRAWS = 100
"""Draws of the principal inertias before giving up on the triangle inequalities (the last draw is kept)."""


def _unit(rng: np.random.Generator, shape: tuple[int, ...], uniform: bool) -> Any:
    """A standard normal draw, or a uniform one on [-1, 1] (the dispersion's value is then the half-width)."""
    return rng.uniform(-1.0, 1.0, shape) if uniform else rng.standard_normal(shape)


def sample_run(campaign: CampaignConfig, base: dict[str, Any], k: int) -> dict[str, Any]:
    """Draw run ``k``: its config (plain data, validated later) and a record of every draw.

    Parameters
    ----------
    campaign : CampaignConfig
        The campaign.
    base : dict
        The resolved base config (every default filled in, ``set`` merged), as plain data.
    k : int
        Run index.

    Returns
    -------
    dict
        ``{"k", "seed", "job", "config", "draws", "inject"}``; ``config`` is the run's config as plain data and
        ``draws`` what was drawn (dispersion values and the faults that struck); with a ``grid``, also ``cell``
        (its name) and ``replicate`` (whose sub-streams the draws come from, :mod:`oacli.campaign.cells`).
    """
    s, d, f = campaign.seed, campaign.dispersions, campaign.faults
    cell, r = cell_and_replicate(campaign, k)  # r: the index of the draws (k without a grid; oacli.campaign.cells)
    data = copy.deepcopy(base) if cell is None else deep_merge(base, cell.overrides)
    draws: dict[str, Any] = {}
    data["seed"] = run_seed(s, r)
    data["name"] = f"{campaign.name}-run-{k:05d}"[:64]
    mass_keys, inertia_keys = _plant_keys(campaign.job)

    uniform = d.distribution == "uniform"
    mass0 = float(_get(data, mass_keys))
    mass = mass0 * (1.0 + 0.01 * d.mass_pct * _unit(substream(s, r, "dispersion/mass"), (), uniform))
    inertia0 = np.asarray(_get(data, inertia_keys), dtype=float)
    rng_i = substream(s, r, "dispersion/inertia")
    for _ in range(MAX_INERTIA_DRAWS):
        inertia = inertia0 * (1.0 + 0.01 * np.asarray(d.inertia_pct) * _unit(rng_i, (3,), uniform))
        if np.all(inertia > 0) and 2 * np.max(inertia) <= np.sum(inertia):  # the triangle inequalities
            break
    _set(data, mass_keys, float(mass))
    draws["mass_kg"] = float(mass)
    if d.principal_axes_rad > 0:
        rng_a = substream(s, r, "dispersion/principal_axes")
        if uniform:  # an angle uniform in [0, max] about a uniformly drawn axis
            direction = rng_a.standard_normal(3)
            rotvec = d.principal_axes_rad * rng_a.uniform() * direction / np.linalg.norm(direction)
        else:
            rotvec = d.principal_axes_rad * rng_a.standard_normal(3)
        rot = Rotation.from_rotvec(rotvec).as_matrix()
        tensor = rot @ np.diag(inertia) @ rot.T
        tensor = 0.5 * (tensor + tensor.T)
        data = deep_merge(data, _tensor_sets(campaign.job, tensor))
        inertia = np.diag(tensor).copy()  # the estimators' truth: the diagonal of the tensor
        draws["inertia_tensor_kgm2"] = tensor.tolist()
    _set(data, inertia_keys, [float(v) for v in inertia])
    draws["inertia_kgm2"] = inertia.tolist()

    truth = data.setdefault("truth", {})
    com0 = np.asarray(truth.get("com_offset_m") or (0.0, 0.0, 0.0), dtype=float)
    com = com0 + np.asarray(d.com_offset_m) * _unit(substream(s, r, "dispersion/com_offset"), (3,), uniform)
    truth["com_offset_m"] = [float(v) for v in np.clip(com, -0.05, 0.05)]

    scale0 = np.asarray(truth.get("actuator_scale") or (1.0,) * 6, dtype=float)
    scale = scale0 * (1.0 + 0.01 * np.asarray(d.actuator_scale_pct)
                      * substream(s, r, "dispersion/actuator_scale").standard_normal(6))
    struck: list[str] = []
    rng = substream(s, r, "fault/actuator_scale_errors")
    if rng.random() < f.actuator_scale_errors.probability:
        scale = scale * (1.0 + 0.01 * f.actuator_scale_errors.std_pct * rng.standard_normal(6))
        struck.append("actuator_scale_errors")
    truth["actuator_scale"] = [float(v) for v in np.clip(scale, *ACTUATOR_SCALE_BOUNDS)]
    draws["actuator_scale"] = truth["actuator_scale"]

    sensors = data.setdefault("sensors", {})
    if d.sensor_noise_pct > 0:
        factor = float(np.exp(0.01 * d.sensor_noise_pct * substream(s, r, "dispersion/sensor_noise")
                              .standard_normal()))
        for key in SENSOR_STD_KEYS:
            sensors[key] = float(sensors.get(key, 0.0)) * factor
        draws["sensor_noise_factor"] = factor
    sim = data.setdefault("simulation", {})
    offset = np.asarray(sim.get("initial_offset_m") or (0.0, 0.0, 0.0), dtype=float)
    offset = offset + np.asarray(d.initial_position_m) * substream(s, r, "dispersion/initial_position") \
        .standard_normal(3)
    sim["initial_offset_m"] = [float(v) for v in offset]
    draws["initial_offset_m"] = sim["initial_offset_m"]

    loc = sensors.setdefault("localisation", {})
    rng = substream(s, r, "fault/localisation_jumps")
    if rng.random() < f.localisation_jumps.probability:
        loc.update(enabled=True, jump_probability=f.localisation_jumps.rate,
                   jump_position_m=list(f.localisation_jumps.position_m),
                   jump_attitude_rad=list(f.localisation_jumps.attitude_rad))
        struck.append("localisation_jumps")
    rng = substream(s, r, "fault/dropped_measurements")
    if rng.random() < f.dropped_measurements.probability:
        loc.update(enabled=True, drop_probability=f.dropped_measurements.rate)
        struck.append("dropped_measurements")
    rng = substream(s, r, "fault/delayed_measurements")
    if rng.random() < f.delayed_measurements.probability:
        loc.update(enabled=True, delay_probability=f.delayed_measurements.rate,
                   delay_mean_s=f.delayed_measurements.mean_delay_s)
        struck.append("delayed_measurements")

    faults = data.setdefault("faults", {})
    rng = substream(s, r, "fault/actuator_saturation")
    if rng.random() < f.actuator_saturation.probability:
        axis = int(rng.integers(6))
        fraction = [1.0] * 6
        fraction[axis] = float(rng.uniform(*f.actuator_saturation.fraction))
        faults["actuator_saturation"] = fraction
        struck.append("actuator_saturation")
        draws["actuator_saturation"] = fraction
    rng = substream(s, r, "fault/controller_stall")
    if rng.random() < f.controller_stall.probability:
        stall = {"start_s": float(rng.uniform(*f.controller_stall.start_s)),
                 "duration_s": float(rng.uniform(*f.controller_stall.duration_s))}
        faults["controller_stall"] = stall
        struck.append("controller_stall")
        draws["controller_stall"] = stall
    draws["faults"] = struck
    inject = campaign.inject.get(k)
    spec = {"k": k, "seed": data["seed"], "job": campaign.job, "config": data, "draws": draws, "inject": inject}
    if cell is not None:
        spec.update(cell=cell.name, replicate=r)
    return spec


__all__ = ["run_seed", "sample_run", "substream"]
