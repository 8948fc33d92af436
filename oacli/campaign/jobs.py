"""What a worker does with one run: build everything from the run's plain config dict, fly the job, report.

:func:`execute_run` is the only function an executor calls. It receives plain data (the run's spec from
:func:`oacli.campaign.sampling.sample_run` and the campaign folder), builds the config, the controller and its
solvers itself (a solved cvxpy problem does not pickle), flies the job into a new attempt folder and returns a plain
dict. A simulation exception becomes status ``failed`` with its traceback; a ``MemoryError`` becomes ``oom`` (an
infrastructure failure the driver retries). A worker that dies returns nothing: the driver sees the executor's
error.

The result hash (:func:`result_hash`) is the SHA-256 of the run's deterministic outputs: its metrics (no wall
times) as canonical JSON and the bytes of its simulated true states, measured states and applied inputs. Equal
hashes mean the same run bit for bit, whichever executor ran it.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
import traceback
from pathlib import Path
from typing import Any

import numpy as np

from oacli.io.atomic import write_text_atomic
from oacli.io.jsonsafe import to_json_safe

BLAS_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS",
            "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS")
"""Environment variables that pin the BLAS/OpenMP thread pools (set before numpy loads in a worker)."""

STATUS_FAILED = "failed"
STATUS_OOM = "oom"
THETA_KEYS = ("mass_kg", "Ixx_kgm2", "Iyy_kgm2", "Izz_kgm2")
"""Keys of the estimate's per-parameter entries (``crb_std``, ``error_pct``) in a mission summary."""
TIMING_KEYS = ("wall_time_s", "solve_time_ms", "step_time_ms", "started_utc", "finished_utc", "created_utc")


def pin_threads() -> None:
    """One BLAS/OpenMP thread in this process (the workers share the machine's cores)."""
    for key in BLAS_ENV:
        os.environ[key] = "1"
    try:
        from threadpoolctl import threadpool_limits  # type: ignore[import-untyped]
        threadpool_limits(1)
    except ImportError:  # pragma: no cover - a dependency; the environment variables still hold for new processes
        pass


def _canonical(value: Any) -> bytes:
    return json.dumps(to_json_safe(value), sort_keys=True, separators=(",", ":"), allow_nan=False).encode()


def result_hash(metrics: dict[str, Any], arrays: list[np.ndarray]) -> str:
    """SHA-256 of ``metrics`` (canonical JSON) and the raw bytes of ``arrays`` (float64, C order).

    Parameters
    ----------
    metrics : dict
        Deterministic results (no wall times).
    arrays : list of ndarray
        Simulated time series.

    Returns
    -------
    str
        Hex digest.
    """
    h = hashlib.sha256(_canonical(metrics))
    for a in arrays:
        arr = np.ascontiguousarray(a, dtype=np.float64)
        h.update(str(arr.shape).encode())
        h.update(arr.tobytes())
    return h.hexdigest()


def _strip_timing(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _strip_timing(v) for k, v in value.items() if k not in TIMING_KEYS}
    if isinstance(value, list):
        return [_strip_timing(v) for v in value]
    return value


def _violations(summary: dict[str, Any]) -> dict[str, int]:
    by_kind = summary.get("constraint_violations_by_kind") or {}
    return {"keep_in": int(by_kind.get("keep_in", 0)), "keep_out": int(by_kind.get("keep_out", 0)),
            "limits": int(by_kind.get("input", 0) + by_kind.get("velocity", 0) + by_kind.get("angular_velocity", 0))}


def track_metrics(summary: dict[str, Any]) -> dict[str, Any]:
    """The campaign's figures of one tracking run (a ``track`` stage summary).

    Parameters
    ----------
    summary : dict
        The stage's ``summary.json`` content.

    Returns
    -------
    dict
        status, violations (keep_in, keep_out, limits), tube_violations, tube_violations_true, fallback_steps,
        solver_failures, rms/max/final position error [m], stalled_steps.
    """
    return {
        "status": summary.get("status"),
        "violations": _violations(summary),
        "tube_violations": int(summary.get("tube_violations") or 0),
        "tube_violations_true": int(summary.get("tube_violations_true") or 0),
        "fallback_steps": int(summary.get("fallback_steps") or 0),
        "solver_failures": int(summary.get("solver_failures") or 0),
        "rms_position_error_m": summary.get("rms_position_error_m"),
        "max_position_error_m": summary.get("max_position_error_m"),
        "final_position_error_m": summary.get("final_position_error_m"),
    }


def _closed_loop(cfg: Any, out: Path) -> tuple[dict[str, Any], list[np.ndarray]]:
    """The tracking controller against the truth plant, no files (``job: closed-loop``)."""
    from oacli.control.tracking import TrackingMPC
    from oacli.sim.simulator import simulate
    from oacli.sim.stall import with_stall
    from oacli.stages.faults import fault_arguments
    from oacli.stages.settings import (
        plant_disturbance,
        robot_model,
        sensor_noise,
        tracking_weights,
        truth_model,
        tube_design_from_config,
    )
    from oacli.stages.track import _track_summary, reference_from_config
    from oacli.stages.track_status import assess_track
    from oacli.stages.track_tube import (
        add_tube_reasons,
        monitored_tube_controller,
        standard_mpc_arguments,
        tube_summary,
    )
    from oacli.status import StatusReport

    reference = reference_from_config(cfg)
    model, plant = robot_model(cfg), truth_model(cfg)
    limits = model.limits
    weights = tracking_weights(cfg)
    monitor = None
    if cfg.controller.type == "tube":
        design = tube_design_from_config(cfg, model=model)
        monitor = monitored_tube_controller(cfg, reference, design, weights, limits, model=model)
        controller: Any = monitor
    else:
        controller = TrackingMPC(reference, model.params, dt_s=cfg.controller.period_s, horizon=cfg.controller.horizon,
                                 weights=weights, limits=limits,
                                 max_consecutive_failures=cfg.controller.max_consecutive_failures,
                                 **standard_mpc_arguments(cfg))
    x0 = reference.x[0].copy()
    x0[0:3] += np.asarray(cfg.simulation.initial_offset_m)
    stall = cfg.faults.controller_stall
    tel = simulate(
        with_stall(controller, stall.start_s, stall.duration_s), x0, plant.params,
        duration_s=reference.duration_s + cfg.simulation.settle_time_s, control_period_s=cfg.controller.period_s,
        plant_period_s=cfg.simulation.plant_period_s, input_limits=limits.input, sensors=sensor_noise(cfg),
        disturbance=plant_disturbance(cfg), rng=np.random.default_rng(cfg.seed),
        actuator_scale=np.asarray(cfg.truth.actuator_scale), com_offset_m=np.asarray(cfg.truth.com_offset_m),
        **fault_arguments(cfg, limits.input),
    )
    summary, _ = _track_summary(cfg, reference, tel, limits)
    findings = StatusReport()
    if monitor is not None:
        history = monitor.history()
        summary.update(tube_summary(monitor, history, tel, cfg))
        add_tube_reasons(findings, summary)
    assess_track(summary, findings).apply(summary)
    from oacli.campaign.study_metrics import response_metrics

    metrics = {**track_metrics(summary), **response_metrics(tel)}  # + lag and hold error (study presets)
    metrics["stalled_steps"] = sum(1 for i in tel.solve_info if i.status == "stalled")
    return metrics, [tel.t_true, tel.x_true, tel.x_measured, tel.u_applied]


def _telemetry_arrays(mcap: Path) -> list[np.ndarray]:
    from oacli.io.mcap_read import read_telemetry

    tel = read_telemetry(mcap)
    return [tel.t_true, tel.x_true, tel.x_measured, tel.u_applied]


def _track(cfg: Any, out: Path) -> tuple[dict[str, Any], list[np.ndarray]]:
    """The ``track`` stage with its files (``job: track``)."""
    from oacli.campaign.study_metrics import response_metrics
    from oacli.io.mcap_read import read_telemetry
    from oacli.stages.track import run_track

    result = run_track(cfg, out=out / "track")
    tel = read_telemetry(out / "track" / "track.mcap")
    metrics = {**track_metrics(result.summary), **response_metrics(tel)}  # + lag and hold error (study presets)
    return metrics, [tel.t_true, tel.x_true, tel.x_measured, tel.u_applied]


def estimate_metrics(estimate: dict[str, Any]) -> dict[str, Any]:
    """Estimation figures of a mission: percent errors and errors in Cramér-Rao standard deviations.

    Parameters
    ----------
    estimate : dict
        The mission summary's ``estimate`` entry.

    Returns
    -------
    dict
        ``error_pct`` (mass, Ixx, Iyy, Izz; signed), ``error_over_crb`` (error ÷ the Cramér-Rao bound's σ).
    """
    theta = np.array([estimate["mass_kg"], *estimate["inertia_kgm2"]], dtype=float)
    truth = np.asarray(estimate["truth_theta"], dtype=float)
    crb_entry = estimate.get("crb_std") or {}
    crb = np.array([crb_entry.get(key, np.nan) if isinstance(crb_entry, dict) else np.nan for key in THETA_KEYS]
                   if isinstance(crb_entry, dict) else crb_entry, dtype=float)
    crb = np.where(np.isfinite(crb), crb, np.nan)
    err = theta - truth
    from oacli.campaign.study_metrics import as_theta_list

    return {"error_pct": (100.0 * err / truth).tolist(),
            "error_over_crb": np.where(crb > 0, err / np.where(crb > 0, crb, 1.0), np.nan).tolist(),
            "cov_reduction_pct": as_theta_list(estimate.get("cov_reduction_pct")),
            "method": estimate.get("method"), "status": estimate.get("status")}


def _mission(cfg: Any, out: Path) -> tuple[dict[str, Any], list[np.ndarray]]:
    """``oacli mission`` (``job: mission``): every segment, the estimate, the baselines."""
    from oacli.config import dump_config
    from oacli.mission.run import run_mission

    folder = out / "mission"
    folder.mkdir()
    write_text_atomic(folder / "config.yaml", dump_config(cfg))
    run_mission(cfg, folder)
    return mission_metrics(folder)


def _excite_estimate(cfg: Any, out: Path) -> tuple[dict[str, Any], list[np.ndarray]]:
    """``excite`` → ``track`` → ``estimate`` (``job: excite-estimate``): the excitation (``excitation.method``, e.g.
    RATTLE's replanning) flown by the tracking controller, then ``oacli estimate`` (``estimation.method``, e.g. the
    flight's ``rls``) on that flight: the commands of ``configs/rattle_flight_rls.yaml`` as one run."""
    from oacli.config import config_from_dict
    from oacli.config.mission import deep_merge
    from oacli.io.mcap_read import read_telemetry
    from oacli.stages.estimate import run_estimate
    from oacli.stages.excite import run_excite
    from oacli.stages.track import run_track

    run_excite(cfg, out=out / "excite")
    data = deep_merge(cfg.model_dump(mode="json"),
                      {"reference": {"source": "file", "file": str(out / "excite" / "excite.mcap")}})
    track_cfg = config_from_dict(data, source=f"{cfg.name} (track)")
    tracked = run_track(track_cfg, out=out / "track")
    estimate = run_estimate(cfg, telemetry=out / "track" / "track.mcap", out=out / "estimate").summary
    metrics = track_metrics(tracked.summary)
    metrics["estimate"] = estimate_metrics(estimate) if estimate.get("truth_theta") else None
    tel = read_telemetry(out / "track" / "track.mcap")
    return metrics, [tel.t_true, tel.x_true, tel.x_measured, tel.u_applied]


def mission_metrics(folder: Path) -> tuple[dict[str, Any], list[np.ndarray]]:
    """The campaign's figures of a complete mission folder, and its tracking stages' time series.

    Parameters
    ----------
    folder : Path
        A mission folder.

    Returns
    -------
    metrics : dict
        Segment 3's tracking figures, violations and tube/fallback counts summed over every tracking stage,
        ``estimate`` (:func:`estimate_metrics`), ``segments`` (each tracking stage's figures).
    arrays : list of ndarray
    """
    from oacli.mission.layout import stage_by_key

    summary = json.loads((folder / "summary.json").read_text())
    tracks = {k: json.loads((stage_by_key(k).folder(folder) / "summary.json").read_text())
              for k, v in summary["stages"].items() if k.endswith("/track") and v.get("status") != "not_run"}
    per_track = {k: track_metrics(v) for k, v in tracks.items()}
    metrics = dict(per_track.get("segment-3/track") or {})  # a mission stopped before segment 3 (issue 29)
    metrics["status"] = summary.get("status")
    if summary.get("stopped"):
        metrics["stopped"] = summary["stopped"]
    metrics["violations"] = {kind: sum(m["violations"][kind] for m in per_track.values())
                             for kind in ("keep_in", "keep_out", "limits")}
    for key in ("tube_violations", "tube_violations_true", "fallback_steps", "solver_failures"):
        metrics[key] = sum(m[key] for m in per_track.values())
    estimate = summary.get("estimate") or {}
    metrics["estimate"] = estimate_metrics(estimate) if estimate.get("mass_kg") is not None else None
    metrics["segments"] = per_track
    from oacli.campaign.study_metrics import comparison_metrics, sequential_estimate

    metrics["comparison"] = comparison_metrics(folder, summary)  # the study presets' figures (segment 3's flights)
    metrics["estimate_sequential"] = sequential_estimate(folder)
    arrays: list[np.ndarray] = []
    for key in sorted(tracks):
        arrays += _telemetry_arrays(stage_by_key(key).mcap(folder))
    return metrics, arrays


JOBS = {"closed-loop": _closed_loop, "track": _track, "mission": _mission, "excite-estimate": _excite_estimate}


def _inject(kind: str | None) -> None:
    """Break this run on purpose (the campaign's ``inject`` testing aid)."""
    if kind == "raise":
        raise RuntimeError("injected failure (campaign inject: raise)")
    if kind == "exit":
        os._exit(17)  # the worker process dies without a word
    if kind == "oom":
        np.ones(2**42, dtype=np.uint8)  # 4 TiB: the allocation fails (MemoryError)
    if kind == "hang":
        time.sleep(1e6)


def new_attempt_dir(run_dir: Path) -> Path:
    """Create the next free ``attempt-N`` folder of a run (exclusively; an existing folder is never reused).

    Parameters
    ----------
    run_dir : Path
        The run's folder.

    Returns
    -------
    Path
    """
    n = 0
    while True:
        path = run_dir / f"attempt-{n}"
        try:
            path.mkdir()
            return path
        except FileExistsError:
            n += 1


def run_job(spec: dict[str, Any], out: Path) -> dict[str, Any]:
    """Fly one run into ``out`` and return its metrics and result hash (no exception handling).

    Parameters
    ----------
    spec : dict
        The run's spec (:func:`oacli.campaign.sampling.sample_run`).
    out : Path
        A new, empty folder for the job's files.

    Returns
    -------
    dict
        ``{"metrics", "hash"}``.
    """
    from oacli.config import config_from_dict

    _inject(spec.get("inject"))
    cfg = config_from_dict(spec["config"], source=f"run {spec['k']}")
    metrics, arrays = JOBS[spec["job"]](cfg, out)
    metrics = _strip_timing(to_json_safe(metrics))
    return {"metrics": metrics, "hash": result_hash(metrics, arrays)}


def execute_run(spec: dict[str, Any], campaign_dir: str) -> dict[str, Any]:
    """The executor's task: run ``spec`` in a new attempt folder of its run and report (module docstring).

    Parameters
    ----------
    spec : dict
        The run's spec.
    campaign_dir : str
        The campaign folder.

    Returns
    -------
    dict
        ``k``, ``status`` (the job's: ok / degraded / unsafe; or failed / oom), ``metrics``, ``hash``,
        ``traceback`` (failed), ``attempt`` (folder, relative to the campaign), ``wall_time_s``, ``pid``.
    """
    pin_threads()
    start = time.perf_counter()
    run_dir = Path(campaign_dir) / "runs" / f"run-{spec['k']:05d}"
    attempt = new_attempt_dir(run_dir)
    out: dict[str, Any] = {"k": spec["k"], "attempt": str(attempt.relative_to(campaign_dir)), "pid": os.getpid()}
    try:
        done = run_job(spec, attempt)
        out.update(status=done["metrics"].get("status") or "ok", metrics=done["metrics"], hash=done["hash"])
    except MemoryError as exc:
        out.update(status=STATUS_OOM, error=f"{type(exc).__name__}: {exc}")
    except Exception as exc:
        out.update(status=STATUS_FAILED, error=f"{type(exc).__name__}: {exc}", traceback=traceback.format_exc())
    out["wall_time_s"] = time.perf_counter() - start
    write_text_atomic(attempt / "result.json", json.dumps(to_json_safe(out), indent=1, allow_nan=False))
    return out


__all__ = ["BLAS_ENV", "execute_run", "pin_threads", "result_hash", "run_job", "track_metrics"]
