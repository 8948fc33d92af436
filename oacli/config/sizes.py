"""Sizes a configuration implies, checked at validation so that no value can exhaust the machine.

A config names durations and rates; their products are the number of simulation steps, reference samples and
so on that a stage will allocate and loop over. A tiny cruise speed, a huge hold or settle time or a
plant rate of 10 MHz would ask for billions of steps (hours of CPU, tens of GiB); these are refused with the
field that asks for them, before anything runs.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import Any

import yaml

from oacli.errors import ConfigError

MAX_SIMULATION_STEPS = 1_000_000
"""Most plant integration steps one simulation may take ((reference duration + settle time) × plant rate):
4.4 h of robot time at Astrobee's 62.5 Hz."""

MAX_PLANT_RATE_HZ = 10_000.0
"""Highest plant integration rate [Hz] (160 × Astrobee's 62.5 Hz control rate)."""

MAX_MESSAGES_PER_TOPIC = 2 * MAX_SIMULATION_STEPS
"""Most messages oacli reads from one MCAP topic (a stage writes at most one per plant step per topic)."""

MAX_MCAP_MESSAGES = 4 * MAX_MESSAGES_PER_TOPIC
"""Most messages oacli reads from one MCAP file."""

MAX_MCAP_CHANNELS = 10_000
"""Most channels (and schemas) oacli reads from one MCAP file (a stage writes about 30)."""

MAX_CONFIG_LIST_ITEMS = 1_000
"""Most items in one list of a config file (the longest lists, waypoints and keep-out zones, hold tens)."""

MAX_CONFIG_MAPPING_KEYS = 1_000
"""Most keys in one mapping of a config file."""

MAX_CONFIG_NODES = 100_000
"""Most YAML nodes (scalars, lists, mappings) in one config file."""

Problem = tuple[tuple[str | int, ...], Any, str]


def _angle_rad(q0: Sequence[float], q1: Sequence[float]) -> float:
    dot = abs(sum(a * b for a, b in zip(q0, q1, strict=True)))
    return 2.0 * math.acos(min(1.0, dot))


def waypoint_duration_parts(cfg: Any) -> dict[tuple[str, ...], float]:
    """Estimated duration [s] of a waypoint reference by the field that sets each part.

    Each leg takes the longer of its translation (distance / cruise speed + cruise speed / acceleration, a
    trapezoidal profile's upper bound) and its rotation (angle / rate + rate / angular acceleration); every
    waypoint is held ``hold_s``.
    """
    ref = cfg.reference
    poses = cfg.reference_poses()
    translate = rotate = 0.0
    for a, b in itertools.pairwise(poses):
        d = math.dist(a.position, b.position)
        t_lin = d / ref.cruise_speed_mps + ref.cruise_speed_mps / ref.acceleration_mps2 if d > 0 else 0.0
        theta = _angle_rad(a.quaternion, b.quaternion)
        t_rot = theta / ref.angular_rate_radps + ref.angular_rate_radps / ref.angular_acceleration_radps2 \
            if theta > 0 else 0.0
        if t_lin >= t_rot:
            translate += t_lin
        else:
            rotate += t_rot
    return {
        ("reference", "cruise_speed_mps"): translate,
        ("reference", "angular_rate_radps"): rotate,
        ("reference", "hold_s"): len(poses) * ref.hold_s,
    }


def steps_message(duration_s: float, rate_hz: float) -> str:
    steps = duration_s * rate_hz
    return (f"implies {steps:.3g} simulation steps ({duration_s:.4g} s × simulation.plant_rate_hz {rate_hz:g} Hz), "
            f"more than the {MAX_SIMULATION_STEPS:.0e} allowed")


def size_problems(cfg: Any) -> list[Problem]:
    """The fields of ``cfg`` (an :class:`~oacli.config.models.OacliConfig`) that ask for too large a run: too many
    steps, then the resource estimate against the budget (:mod:`oacli.config.budget`)."""
    from oacli.config.budget import budget_problems, excitation_problems

    problems: list[Problem] = []
    sim = cfg.simulation
    rate = sim.plant_rate_hz
    if rate > MAX_PLANT_RATE_HZ:
        return [(("simulation", "plant_rate_hz"), rate, f"must be <= {MAX_PLANT_RATE_HZ:g} Hz")]
    problems += excitation_problems(cfg, MAX_SIMULATION_STEPS, steps_message)
    if sim.settle_time_s * rate > MAX_SIMULATION_STEPS:
        problems.append((("simulation", "settle_time_s"), sim.settle_time_s, steps_message(sim.settle_time_s, rate)))
        return problems
    duration = float(sim.settle_time_s)
    field: tuple[str, ...] = ("simulation", "settle_time_s")
    if cfg.reference.source == "waypoints" and len(cfg.reference.waypoints) >= 1:
        try:
            parts = waypoint_duration_parts(cfg)
        except KeyError:  # an unknown waypoint name: reported by the cross-check
            return problems
        total = sum(parts.values()) + sim.settle_time_s
        loc = max(parts, key=lambda k: parts[k])
        if total * rate > MAX_SIMULATION_STEPS:
            value = getattr(cfg.reference, loc[1])
            if loc == ("reference", "cruise_speed_mps") and _acceleration_dominates(cfg):
                loc, value = ("reference", "acceleration_mps2"), cfg.reference.acceleration_mps2
            problems.append((loc, value, steps_message(total, rate)))
            return problems
        duration = total
        if parts[loc] > sim.settle_time_s:
            field = loc
    return problems + budget_problems(cfg, duration, field)


def _acceleration_dominates(cfg: Any) -> bool:
    """Whether the translation time of a waypoint reference is mostly the ramps (cruise speed / acceleration, a
    tiny ``acceleration_mps2``) rather than the cruise (distance / cruise speed, a tiny ``cruise_speed_mps``)."""
    ref = cfg.reference
    poses = cfg.reference_poses()
    cruise = sum(math.dist(a.position, b.position) for a, b in itertools.pairwise(poses)) / ref.cruise_speed_mps
    ramps = (len(poses) - 1) * ref.cruise_speed_mps / ref.acceleration_mps2
    return ramps > cruise


def check_simulation_length(duration_s: float, rate_hz: float, what: str) -> str | None:
    """A one-line problem when simulating ``duration_s`` at ``rate_hz`` would take too many steps, else None.

    Parameters
    ----------
    duration_s : float
        Reference duration plus settle time [s].
    rate_hz : float
        Plant rate [Hz].
    what : str
        What sets the duration (e.g. ``"--reference runs/x/smooth.mcap"``), starting the message.
    """
    if not math.isfinite(duration_s) or duration_s * rate_hz > MAX_SIMULATION_STEPS:
        return f"{what}: spans {duration_s:.4g} s: {steps_message(duration_s, rate_hz)}"
    return None


class ConfigSizeError(ConfigError):
    """A config file holds a list, a mapping or a document too large (raised while it is parsed; the loader's
    caller prefixes the file name)."""


class BoundedComposer:
    """Mixin for a PyYAML loader that refuses, while the text is still being parsed, a list longer than
    :data:`MAX_CONFIG_LIST_ITEMS`, a mapping with more than :data:`MAX_CONFIG_MAPPING_KEYS` keys and a document of
    more than :data:`MAX_CONFIG_NODES` nodes (aliases count the nodes they repeat), with a
    :class:`ConfigSizeError` naming the field and the limit.

    PyYAML scans lazily, so a 1 MiB config holding a list of half a million numbers (a minute of parsing in pure
    Python) is refused after the first :data:`MAX_CONFIG_LIST_ITEMS` items, in milliseconds.
    """

    def compose_document(self) -> Any:
        self._bounded_path: list[str] = []
        self._bounded_nodes = 0
        self._bounded_sizes: dict[int, int] = {}
        return super().compose_document()  # type: ignore[misc]

    def _bounded_field(self) -> str:
        return ".".join(self._bounded_path) or "the document"

    def _bounded_refuse(self, what: str, limit: int, name: str, mark: Any) -> ConfigSizeError:
        line = f" (line {mark.line + 1})" if mark is not None else ""
        return ConfigSizeError(f"{self._bounded_field()}: {what}{line}: a config holds at most {limit} "
                           f"(oacli.config.sizes.{name})")

    def compose_node(self, parent: Any, index: Any) -> Any:
        event = self.peek_event()  # type: ignore[attr-defined]
        mark = getattr(event, "start_mark", None)
        if isinstance(parent, yaml.SequenceNode):
            if index >= MAX_CONFIG_LIST_ITEMS:
                raise self._bounded_refuse(f"a list of more than {MAX_CONFIG_LIST_ITEMS} items",
                                           MAX_CONFIG_LIST_ITEMS, "MAX_CONFIG_LIST_ITEMS", mark)
            self._bounded_path.append(str(index))
        elif isinstance(parent, yaml.MappingNode):
            if index is None and len(parent.value) >= MAX_CONFIG_MAPPING_KEYS:
                raise self._bounded_refuse(f"a mapping of more than {MAX_CONFIG_MAPPING_KEYS} keys",
                                           MAX_CONFIG_MAPPING_KEYS, "MAX_CONFIG_MAPPING_KEYS", mark)
            key = index.value if isinstance(index, yaml.ScalarNode) else "<key>"
            self._bounded_path.append(str(key)[:60])
        before = self._bounded_nodes
        self._bounded_nodes += 1
        if self._bounded_nodes > MAX_CONFIG_NODES:
            raise self._bounded_refuse(f"more than {MAX_CONFIG_NODES} values in the file", MAX_CONFIG_NODES,
                                       "MAX_CONFIG_NODES", mark)
        alias = isinstance(event, yaml.AliasEvent)
        node = super().compose_node(parent, index)  # type: ignore[misc]
        if alias:  # the alias repeats the anchored node's values
            self._bounded_nodes += self._bounded_sizes.get(id(node), 1) - 1
            if self._bounded_nodes > MAX_CONFIG_NODES:
                raise self._bounded_refuse(f"more than {MAX_CONFIG_NODES} values in the file (aliases "
                                           "included)", MAX_CONFIG_NODES, "MAX_CONFIG_NODES", mark)
        elif getattr(event, "anchor", None) is not None:
            self._bounded_sizes[id(node)] = self._bounded_nodes - before
        if parent is not None:
            self._bounded_path.pop()
        return node
