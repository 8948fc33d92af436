"""Beyond W: measure the realised disturbance of the tube MPC every step and respond when it leaves W.

The tube guarantee (Mayne, Seron & Raković 2005; [Doerr2021] Eqs. 15-28) holds only while every one-step
disturbance lies in the design's W. :class:`TubeMonitor` owns the :class:`oacli.control.tube_mpc.TubeMPC` and, at
each control step k, measures the realised one-step disturbance of the translational error model per world axis,

    w_k = x̃_k − (A x̃_{k−1} + B u_{k−1}),

with ``x̃ = [position, velocity]`` the measured state of the axis, ``A, B`` the design's exact double integrator at
the control period (the model mass) and ``u_{k−1}`` the force applied over the last period, which the controller
knows as its own command clipped to the actuator limit. With measurement noise this is the disturbance of the
measured error ``ẽ⁺ = A_K ẽ + w + n⁺ − A n`` that W must bound (:mod:`oacli.control.disturbance`). A step is a
*violation* when ``w_k ∉ W`` on some axis (beyond a relative tolerance of W's size).

Responses (``controller.tube.beyond_w``):

* ``redesign`` (default): re-design the tube with the measured bound, i.e. W grown to contain the box of the
  running maximum of ``|w|`` per axis and component times ``1 + margin``
  (:func:`oacli.control.tube_design.design_translation_tube` with a bounded term budget, timed), then continue with
  a new TubeMPC on the new design. When the redesign is infeasible (W too large for the actuators), or after
  ``max_redesigns`` redesigns, the safe hold of the current TubeMPC is latched;
* ``hold``: latch the current TubeMPC's safe hold at the first violation;
* ``ignore``: only measure, count and log.

Every response is recorded (:attr:`TubeMonitor.events`); :meth:`TubeMonitor.history` merges the histories of the
successive TubeMPCs, and :meth:`TubeMonitor.disturbance_record` holds the measured w against W per step.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from oacli.control.tube_design import TubeDesign
from oacli.control.tube_mpc import TubeHistory, TubeMPC
from oacli.errors import InfeasibleError
from oacli.types import ControlStep, SolveInfo

RESPONSES = ("redesign", "hold", "ignore")

#: A measured w counts as outside W only beyond this fraction of W's largest offset (rounding).
W_TOLERANCE_REL = 1e-6


@dataclass(frozen=True)
class BeyondWEvent:
    """One response to a disturbance beyond W.

    Attributes
    ----------
    t : float
        Step time [s].
    response : str
        ``redesign`` (a new tube is in use from this step), ``hold`` (safe hold latched) or ``ignore``
        (first violation, logged only).
    reason : str
        What happened, for the log.
    measured_max : ndarray, shape (3, 2)
        Running maximum of ``|w|`` per axis ``[position m, velocity m/s]`` up to this step.
    w_before, w_after : ndarray, shape (3, 2)
        W's half-widths per axis before and after the response (the same unless redesigned).
    redesign_time_s : float or None
        Wall time of the redesign [s] (None when none was attempted).
    """

    t: float
    response: str
    reason: str
    measured_max: np.ndarray
    w_before: np.ndarray
    w_after: np.ndarray
    redesign_time_s: float | None


@dataclass(frozen=True)
class DisturbanceRecord:
    """The measured one-step disturbance against W at each of the K control steps.

    Attributes
    ----------
    t : ndarray, shape (K,)
    w : ndarray, shape (K, 3, 2)
        Measured ``w_k`` per axis ``[position m, velocity m/s]`` (NaN where not measured: the first step).
    w_half_widths : ndarray, shape (K, 3, 2)
        Half-widths of the W in use at the step.
    margin : ndarray, shape (K,)
        ``min`` over axes and facets of ``b − a·w`` (≥ 0 inside W; NaN where not measured).
    violated : ndarray of bool, shape (K,)
    design_index : ndarray of int, shape (K,)
        Which design (0: the initial one) drove the step.
    """

    t: np.ndarray
    w: np.ndarray
    w_half_widths: np.ndarray
    margin: np.ndarray
    violated: np.ndarray
    design_index: np.ndarray


def half_widths(design: TubeDesign) -> np.ndarray:
    """W's half-widths per axis ``[position m, velocity m/s]``.

    Parameters
    ----------
    design : TubeDesign

    Returns
    -------
    ndarray, shape (3, 2)
    """
    return np.array([ax.disturbance.half_widths for ax in design.axes])


def box_half_widths(design: TubeDesign) -> np.ndarray:
    """The box part of W per axis (mass + force + given box terms, before noise and scaling).

    Parameters
    ----------
    design : TubeDesign

    Returns
    -------
    ndarray, shape (3, 2)
        Half-widths ``[position m, velocity m/s]`` per axis.
    """
    return np.array([ax.disturbance.mass_term + ax.disturbance.force_term + ax.disturbance.box_term
                     for ax in design.axes])


def extra_box_for(design: TubeDesign, measured_max: np.ndarray, margin: float) -> np.ndarray:
    """Box half-widths (3, 2) to add to W's box part so that the new W contains ``(1 + margin)·measured_max``.

    The new W is ``box(h + extra) ⊕ N ⊕ (−A N)`` (:mod:`oacli.control.disturbance`) with ``h`` the current box
    part: it contains the old W (``extra ≥ 0``) and the box ``(1 + margin)·measured_max`` (the noise sets hold 0).

    Parameters
    ----------
    design : TubeDesign
        The current design.
    measured_max : ndarray, shape (3, 2)
        Largest measured ``|w|`` per axis ``[position m, velocity m/s]``.
    margin : float
        Relative margin on the measured bound (>= 0).

    Returns
    -------
    ndarray, shape (3, 2)
        Extra box half-widths (>= 0).
    """
    return np.asarray(np.maximum((1.0 + margin) * np.asarray(measured_max, dtype=float) - box_half_widths(design), 0.0))


class TubeMonitor:
    """A TubeMPC with the beyond-W check and response of the module docstring (simulator ``Controller``).

    Parameters
    ----------
    factory : callable
        ``factory(design) -> TubeMPC``: a tube controller around a design (same reference, weights, limits).
    design : TubeDesign
        The initial design.
    response : {"redesign", "hold", "ignore"}
    actuator_force_limit_N : ndarray, shape (3,)
        Force saturation of the actuators per world axis [N] (the applied force is the command clipped to it).
    redesign : callable, optional
        ``redesign(extra_box) -> TubeDesign`` with ``extra_box (3, 2)`` added to W's box half-widths; raises
        :class:`oacli.errors.InfeasibleError` when no tube exists. Required for ``response="redesign"``.
    margin : float
        Relative margin on the measured bound for a redesign (0.5: W grows to 1.5 × the largest measured |w|).
    max_redesigns : int
        Redesigns allowed in a run; a further violation latches the safe hold.
    clock : callable
        Wall clock for the redesign time [s].
    noise_allowance : ndarray, shape (3, 2), optional
        ``[position m, velocity m/s]`` half-widths per axis of the box the measurement noise adds to the measured
        ``w`` (``n⁺ − A n``); a step is a violation only when ``w`` leaves ``W ⊕ box``, so declared sensor noise
        does not read as a disturbance beyond W (default: none).
    """

    def __init__(
        self,
        factory: Callable[[TubeDesign], TubeMPC],
        design: TubeDesign,
        *,
        response: str = "redesign",
        actuator_force_limit_N: np.ndarray,
        redesign: Callable[[np.ndarray], TubeDesign] | None = None,
        margin: float = 0.5,
        max_redesigns: int = 3,
        clock: Callable[[], float] = time.perf_counter,
        noise_allowance: np.ndarray | None = None,
    ) -> None:
        if response not in RESPONSES:
            raise ValueError(f"response must be one of {RESPONSES}, got {response!r}")
        if response == "redesign" and redesign is None:
            raise ValueError("response 'redesign' needs a redesign function")
        if margin < 0 or max_redesigns < 0:
            raise ValueError("margin and max_redesigns must be >= 0")
        self.factory, self.response, self.redesign_fn = factory, response, redesign
        self.margin, self.max_redesigns, self.clock = float(margin), int(max_redesigns), clock
        self.force_limit = np.asarray(actuator_force_limit_N, dtype=float).reshape(3)
        self.noise_allowance = (np.zeros((3, 2)) if noise_allowance is None
                                else np.asarray(noise_allowance, dtype=float).reshape(3, 2))
        self.designs: list[tuple[float, TubeDesign]] = [(0.0, design)]
        self._hw_cache: tuple[TubeDesign, np.ndarray] | None = None  # W's half-widths of the design in use
        self._w_cache: dict[int, tuple[TubeDesign, list[tuple[np.ndarray, np.ndarray, np.ndarray, float]]]] = {}
        self.controllers: list[TubeMPC] = [factory(design)]
        self.events: list[BeyondWEvent] = []
        self.held = False
        self._prev: tuple[float, np.ndarray, np.ndarray] | None = None  # (t, x̃ translation (6,), applied force)
        self._max_abs = np.zeros((3, 2))
        self._rec: dict[str, list[Any]] = {k: [] for k in ("t", "w", "hw", "margin", "violated", "design")}

    # -- properties --------------------------------------------------------------------------------------------

    @property
    def design(self) -> TubeDesign:
        """The design in use."""
        return self.designs[-1][1]

    @property
    def controller(self) -> TubeMPC:
        """The TubeMPC in use."""
        return self.controllers[-1]

    @property
    def redesigns(self) -> int:
        """Redesigns done so far."""
        return len(self.designs) - 1

    # -- measurement -------------------------------------------------------------------------------------------

    def _measure(self, t: float, x_t: np.ndarray) -> tuple[np.ndarray, float, bool]:
        """``(w (3, 2), margin, violated)`` of this step (NaNs and no violation when not measurable)."""
        design = self.design
        prev = self._prev
        if prev is None or abs((t - prev[0]) - design.dt_s) > 1e-9 * max(1.0, design.dt_s):
            return np.full((3, 2), np.nan), float("nan"), False
        _, x_prev, u_prev = prev
        w = np.empty((3, 2))
        margin = np.inf
        violated = False
        for i, (ax, (w_a, w_b, w_noise, tolerance)) in enumerate(zip(design.axes, self._w_rows(design), strict=True)):
            e_now = np.array([x_t[i], x_t[i + 3]])
            e_prev = np.array([x_prev[i], x_prev[i + 3]])
            w[i] = e_now - ax.a @ e_prev - ax.b[:, 0] * u_prev[i]
            slack = w_b - w_a @ w[i] + w_noise
            margin = min(margin, float(np.min(slack)))
            violated |= bool(np.any(slack < tolerance))
        return w, margin, violated

    def _w_rows(self, design: TubeDesign) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, float]]:
        """Per axis ``(H, b, |H| n, −tol·max|b|)`` of W's rows ``H w ≤ b`` with the noise allowance n, computed once
        per design (the constant parts of :meth:`_measure`'s check)."""
        key = id(design)
        cached = self._w_cache.get(key)
        if cached is None or cached[0] is not design:
            rows = []
            for i, ax in enumerate(design.axes):
                wset = ax.disturbance.w
                rows.append((wset.a, wset.b, np.abs(wset.a) @ self.noise_allowance[i],
                             -W_TOLERANCE_REL * float(np.max(np.abs(wset.b)))))
            cached = (design, rows)
            self._w_cache[key] = cached
        return cached[1]

    # -- responses ---------------------------------------------------------------------------------------------

    def _hold(self, t: float, x: np.ndarray, reason: str, redesign_time: float | None) -> None:
        self.controller.enter_safe_hold(x[6:10])
        self.held = True
        hw = half_widths(self.design)
        self.events.append(BeyondWEvent(t, "hold", reason, self._max_abs.copy(), hw, hw, redesign_time))

    def _redesign(self, t: float, x: np.ndarray) -> None:
        before = half_widths(self.design)
        if self.redesigns >= self.max_redesigns:
            self._hold(t, x, f"the disturbance left W again after {self.redesigns} redesigns", None)
            return
        extra = extra_box_for(self.design, self._max_abs, self.margin)
        start = self.clock()
        if self.redesign_fn is None:  # __init__ refuses "redesign" without one
            raise RuntimeError("redesign response without a redesign function")
        try:
            new = self.redesign_fn(extra)
            controller = self.factory(new)
        except InfeasibleError as exc:
            elapsed = self.clock() - start
            first = exc.problems[0].split(". ")[0].removeprefix("controller.tube: ")
            self._hold(t, x, f"redesign infeasible: {first}", elapsed)
            return
        elapsed = self.clock() - start
        self.designs.append((t, new))
        self.controllers.append(controller)
        self.events.append(BeyondWEvent(t, "redesign", f"W grown to {1 + self.margin:g} × the measured bound",
                                        self._max_abs.copy(), before, half_widths(new), elapsed))

    # -- the controller step -----------------------------------------------------------------------------------

    def step(self, t: float, x_measured: np.ndarray) -> ControlStep:
        """One control step at time ``t`` [s] (simulator ``Controller`` protocol).

        Parameters
        ----------
        t : float
            Mission time [s].
        x_measured : ndarray, shape (13,)
            Measured state.

        Returns
        -------
        ControlStep
            The inner TubeMPC's step, its wall time including the check and any redesign.
        """
        x = np.asarray(x_measured, dtype=float)
        x_t = x[0:6]
        start = self.clock()
        w, margin, violated = self._measure(t, x_t)
        if np.all(np.isfinite(w)):
            self._max_abs = np.maximum(self._max_abs, np.abs(w))
        design_used = self.redesigns
        if violated and not self.held:
            if self.response == "redesign":
                self._redesign(t, x)
            elif self.response == "hold":
                self._hold(t, x, "the disturbance left W", None)
            elif not self.events:
                hw = half_widths(self.design)
                self.events.append(BeyondWEvent(t, "ignore", "the disturbance left W (beyond_w: ignore)",
                                                self._max_abs.copy(), hw, hw, None))
        rec = self._rec
        design_now = self.designs[design_used][1]
        if self._hw_cache is None or self._hw_cache[0] is not design_now:
            self._hw_cache = (design_now, half_widths(design_now))
        for key, value in (("t", t), ("w", w), ("hw", self._hw_cache[1].copy()),
                           ("margin", margin), ("violated", violated), ("design", self.redesigns)):
            rec[key].append(value)
        before_step = self.clock()
        step = self.controller.step(t, x)
        self._prev = (t, x_t.copy(), np.clip(np.asarray(step.u[0:3], dtype=float), -self.force_limit,
                                              self.force_limit))
        # The step's wall time includes the check and any redesign done for it.
        inner = step.info
        info = SolveInfo(inner.status, inner.success, inner.objective, inner.iterations, inner.solve_time_s,
                         inner.step_time_s + (before_step - start))
        return ControlStep(step.u, info, step.x_reference)

    # -- records -----------------------------------------------------------------------------------------------

    def history(self) -> TubeHistory:
        """The histories of the successive TubeMPCs, concatenated.

        Returns
        -------
        TubeHistory
            One entry per control step.
        """
        parts = [c.history() for c in self.controllers]
        if len(parts) == 1:
            return parts[0]
        merged: dict[str, Any] = {}
        for name in TubeHistory.__dataclass_fields__:
            values = [getattr(p, name) for p in parts]
            merged[name] = tuple(m for v in values for m in v) if name == "mode" else np.concatenate(values)
        return TubeHistory(**merged)

    def disturbance_record(self) -> DisturbanceRecord:
        """The measured w against W at every step so far.

        Returns
        -------
        DisturbanceRecord
        """
        rec = self._rec
        k = len(rec["t"])
        return DisturbanceRecord(
            t=np.array(rec["t"], dtype=float),
            w=np.array(rec["w"], dtype=float).reshape(k, 3, 2),
            w_half_widths=np.array(rec["hw"], dtype=float).reshape(k, 3, 2),
            margin=np.array(rec["margin"], dtype=float),
            violated=np.array(rec["violated"], dtype=bool),
            design_index=np.array(rec["design"], dtype=int),
        )
