"""Settings of the trajectory polish (:mod:`oacli.planning.polish`)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class PolishSettings:
    """Settings of :func:`polish_trajectory`.

    Attributes
    ----------
    iterations : int
        SCP subproblems solved at most.
    step_s : float
        Piece length of the polish grid [s] (a multiple of the output step).
    effort_weight : float
        ``w_e`` [m/(N²·s)], >= 0: weight of ``Σ h ‖f‖²`` against the length [m] (regularises the forces).
    buffer_penalty : float
        λ [-], > 0: exact penalty on the virtual buffers (metres of length per metre of violation).
    trust_radius_m : float
        Initial trust radius Δ [m] (per axis, on the knot positions).
    min_trust_radius_m, max_trust_radius_m : float
        The polish stops when Δ falls below the minimum; Δ never grows beyond the maximum [m].
    clearance_m : float
        μ [m], >= 0: extra distance kept from every keep-out zone (covers the exact re-propagation).
    limit_margin : float
        ε [-]: the subproblem keeps ``|f_i| <= (1 − ε) F_i`` and ``|v_i| <= (1 − ε) V_i``.
    tolerance : float
        Stop when a certified step lowers the subproblem objective by less than this fraction.
    stall_iterations : int
        Stop after this many certified steps in a row that shorten the best exact path length by less than
        ``stall_gain`` each (the objective may still creep down through its effort term while the length no longer
        improves); 0 never stops for that.
    stall_gain : float
        [-]: the relative shortening below which a certified step counts towards ``stall_iterations``
        (3e-6: 17 µm on S2's 5.6 m path; at least :data:`~oacli.planning.polish.MIN_GAIN`).
    prediction : float
        [-], >= 0: look-ahead of the keep-out linearisation. After a certified accepted step in the direction of
        the one before (cosine of the knot position changes at least ``prediction_min_cos``), the next
        subproblem's half-spaces are taken at the reference moved on by ``prediction`` times that step
        (:mod:`oacli.planning.polish`, "Look-ahead"); 0: always at the reference.
    prediction_min_cos : float
        [-]: the least cosine between two successive steps for a look-ahead.
    rest_tolerance : float
        A trailing piece within this distance [m] and speed [m/s] of the goal at rest counts as arrived.
    backend : str
        ``direct``: the subproblem assembled directly for Clarabel (:mod:`oacli.planning.polish_conic`, no
        canonicalisation); ``cvxpy``: the DPP cvxpy formulation (:mod:`oacli.planning.polish_subproblem`), the
        reference the tests compare with.
    active_set : bool
        ``direct`` only: solve with a working set of the force/velocity rows and the cost cap, grown until the
        solution satisfies the rest (:mod:`oacli.planning.polish_conic`; the same optimum, less time); False: every
        row in every solve.
    """

    iterations: int = 30
    step_s: float = 0.5
    effort_weight: float = 0.01
    buffer_penalty: float = 1e3
    trust_radius_m: float = 0.05
    min_trust_radius_m: float = 1e-4
    max_trust_radius_m: float = 0.4
    clearance_m: float = 1e-4
    limit_margin: float = 1e-6
    tolerance: float = 1e-5
    stall_iterations: int = 2
    stall_gain: float = 3e-6
    prediction: float = 1.5
    prediction_min_cos: float = 0.97
    rest_tolerance: float = 1e-7
    backend: str = "direct"
    active_set: bool = True
