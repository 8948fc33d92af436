"""A stalled controller: the actuators hold the last command ([ReSWARM2023] §6.2.1 flight faults).

From ``start_s`` for ``duration_s`` the command bus stalls: the wrapped controller keeps running (its records,
e.g. a tube monitor's history, stay aligned with the simulation) but the actuators receive the last command sent
before the stall, unchanged. After the stall the controller's commands pass again. The record says so: the step's
:class:`oacli.types.SolveInfo` gets status ``stalled`` (success unchanged), so the telemetry shows when it happened.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from oacli.types import Controller, ControlStep

STALLED_STATUS = "stalled"


class StalledController:
    """Wrap ``inner`` so that its output is frozen during ``[start_s, start_s + duration_s)``.

    Parameters
    ----------
    inner : Controller
        The controller.
    start_s, duration_s : float
        Stall window [s] (stage time, the simulator's ``t``).
    """

    def __init__(self, inner: Controller, start_s: float, duration_s: float) -> None:
        self.inner = inner
        self.start_s = float(start_s)
        self.end_s = float(start_s) + float(duration_s)
        self._held: np.ndarray | None = None
        self.stalled_steps = 0

    def step(self, t: float, x_measured: np.ndarray) -> ControlStep:
        """The inner controller's step, with its input replaced by the held one while stalled.

        Parameters
        ----------
        t : float
            Stage time [s].
        x_measured : ndarray, shape (13,)

        Returns
        -------
        ControlStep
        """
        out = self.inner.step(t, x_measured)
        if self.start_s <= t < self.end_s:
            if self._held is None:  # stalled from the first step: nothing was sent yet, the actuators are idle
                self._held = np.zeros_like(np.asarray(out.u, dtype=float))
            self.stalled_steps += 1
            return ControlStep(u=self._held.copy(), info=replace(out.info, status=STALLED_STATUS),
                               x_reference=out.x_reference)
        self._held = np.array(out.u, dtype=float)
        return out


def with_stall(controller: Controller, start_s: float, duration_s: float) -> Controller:
    """``controller`` wrapped in :class:`StalledController`, or unchanged when ``duration_s`` is 0.

    Parameters
    ----------
    controller : Controller
    start_s, duration_s : float
        Stall window [s].

    Returns
    -------
    Controller
    """
    if duration_s <= 0:
        return controller
    return StalledController(controller, start_s, duration_s)


__all__ = ["STALLED_STATUS", "StalledController", "with_stall"]
