"""The track stage's flight-like measurement streams (``sensors.imu``, ``sensors.localisation``).

Built after the closed loop from its true trajectory and delivered input (:mod:`oacli.sim.imu`,
:mod:`oacli.sim.localisation`), each from its own named sub-stream of the seed (:mod:`oacli.sim.substreams`), so
the controller's run -- which keeps seeing ``/state/measured`` -- is unchanged by them. Written as ``/imu`` and
``/localisation`` (docs/mcap.md); ``oacli estimate`` reads them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from oacli.config import OacliConfig
from oacli.io import mcap_schema as ms
from oacli.io.mcap_io import StageMcapWriter
from oacli.sim.delivered import DeliveredInput
from oacli.sim.imu import ImuModel, ImuSamples, simulate_imu
from oacli.sim.localisation import (
    LocalisationMessages,
    LocalisationModel,
    localisation_stamps,
    simulate_localisation,
)
from oacli.sim.substreams import sensor_rng
from oacli.stages.settings import sensor_noise
from oacli.types import Telemetry

__all__ = ["FlownSensors", "flown_sensors", "write_flown_sensor_topics"]


@dataclass(frozen=True)
class FlownSensors:
    """The simulated IMU readings and localisation messages of a run (None when off)."""

    imu: ImuSamples | None
    localisation: LocalisationMessages | None

    def summary(self) -> dict[str, Any]:
        """Counts and biases for ``summary.json`` (``sensors``).

        Returns
        -------
        dict
        """
        out: dict[str, Any] = {}
        if self.imu is not None:
            out["imu"] = {"samples": int(self.imu.t.size),
                          "accelerometer_bias_mps2": self.imu.accelerometer_bias_mps2[0].tolist(),
                          "gyro_bias_radps": self.imu.gyro_bias_radps[0].tolist()}
        if self.localisation is not None:
            out["localisation"] = self.localisation.counts()
        return out


def flown_sensors(cfg: OacliConfig, tel: Telemetry) -> FlownSensors | None:
    """The streams ``cfg.sensors`` switches on for the run ``tel`` (None when none is).

    Parameters
    ----------
    cfg : OacliConfig
    tel : Telemetry

    Returns
    -------
    FlownSensors or None
    """
    s = cfg.sensors
    if not (s.imu.enabled or s.localisation.enabled):
        return None
    truth = cfg.truth_params()
    delivered = DeliveredInput.from_telemetry(tel, np.asarray(cfg.truth.actuator_scale),
                                              np.asarray(cfg.truth.com_offset_m))
    imu = loc = None
    if s.imu.enabled:
        model = ImuModel(**s.imu.model_dump(exclude={"enabled"}))
        imu = simulate_imu(tel.t_true, tel.x_true, delivered.force_world(tel.t_true, tel.x_true), truth, model,
                           sensor_rng(cfg.seed, "imu"))
    if s.localisation.enabled:
        lc = s.localisation
        stamps = localisation_stamps(float(tel.t_true[-1]), lc.rate_hz)
        x = delivered.states_at(stamps, tel.t_true, tel.x_true, truth)
        model_l = LocalisationModel(
            rate_hz=lc.rate_hz, noise=sensor_noise(cfg), jump_probability=lc.jump_probability,
            drop_probability=lc.drop_probability, delay_probability=lc.delay_probability,
            jump_position_m=(lc.jump_position_m[0], lc.jump_position_m[1]),
            jump_attitude_rad=(lc.jump_attitude_rad[0], lc.jump_attitude_rad[1]),
            delay_mean_s=lc.delay_mean_s,
        )
        loc = simulate_localisation(stamps, x, model_l, sensor_rng(cfg.seed, "localisation"))
    return FlownSensors(imu, loc)


def write_flown_sensor_topics(writer: StageMcapWriter, flown: FlownSensors) -> None:
    """Write ``/imu`` and ``/localisation`` (localisation messages in arrival order, at their arrival time).

    Parameters
    ----------
    writer : StageMcapWriter
    flown : FlownSensors
    """
    if flown.imu is not None:
        imu = flown.imu
        for t, a, w in zip(imu.t.tolist(), imu.specific_force_mps2.tolist(), imu.angular_rate_radps.tolist(),
                           strict=True):
            writer.write_json(ms.TOPIC_IMU, ms.IMU_SAMPLE, ms.IMU_SAMPLE_SCHEMA, t,
                              {"linear_acceleration": a, "angular_velocity": w})
    if flown.localisation is not None:
        loc = flown.localisation
        for t, stamp, x in zip(loc.arrival_s.tolist(), loc.stamp_s.tolist(), loc.x.tolist(), strict=True):
            writer.write_json(ms.TOPIC_LOCALISATION, ms.LOCALISATION_SAMPLE, ms.LOCALISATION_SAMPLE_SCHEMA, t,
                              {"stamp": stamp, "position": x[0:3], "velocity": x[3:6], "quaternion": x[6:10],
                               "angular_velocity": x[10:13]})
