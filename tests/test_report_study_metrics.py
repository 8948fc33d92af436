"""The study presets' per-run figures against closed forms: the lag of a delayed path, the error while holding, the
closest approach to a keep-out ellipsoid, and the flat per-run figures the cells aggregate."""

from __future__ import annotations

import math

import numpy as np
import pytest

from oacli.campaign.aggregate import run_events, run_figures
from oacli.campaign.study_metrics import hold_error, keep_out_clearance_m, tracking_lag
from oacli.geometry.shapes import Ellipsoid, Scene


def test_tracking_lag_finds_the_delay_of_a_delayed_path():
    t = np.arange(0.0, 40.0, 0.016)
    ref = np.column_stack([0.05 * t, 0.02 * np.sin(0.3 * t), np.zeros_like(t)])
    delay = 0.8
    flown = np.column_stack([np.interp(t - delay, t, ref[:, i]) for i in range(3)])
    flown += 0.001 * np.random.default_rng(0).standard_normal(flown.shape)
    lag, residual = tracking_lag(t, flown, t, ref)
    assert lag == pytest.approx(delay, abs=0.02)
    assert residual == pytest.approx(0.001 * math.sqrt(3), rel=0.1)  # what is left: the noise
    assert tracking_lag(t, ref, t, ref) == (0.0, 0.0)


def test_hold_error_counts_only_the_settled_hold():
    t = np.arange(0.0, 20.0, 0.2)
    ref = np.zeros((t.size, 13))
    ref[:, 0] = np.minimum(t, 10.0) * 0.05  # moves for 10 s, then holds at 0.5 m
    ref[t < 10.0, 3] = 0.05
    r = ref[:, 0:3].copy()
    r[:, 1] = np.where(t >= 12.0, 0.003, 0.5)  # a 3 mm offset after settling; a large one before
    rms, worst = hold_error(t, r, ref, settle_s=2.0)
    assert rms == pytest.approx(0.003) and worst == pytest.approx(0.003)
    moving = ref.copy()
    moving[:, 3] = 0.05
    assert hold_error(t, r, moving) == (None, None)


def test_keep_out_clearance_of_a_sphere():
    scene = Scene(keep_in=(), keep_out=(Ellipsoid.from_semi_axes(np.zeros(3), np.full(3, 0.5)),))
    path = np.array([[2.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.2, 0.0]])
    assert keep_out_clearance_m(path, scene, 0.25) == pytest.approx(1.0 - 0.5 - 0.25)
    inside = np.array([[0.6, 0.0, 0.0]])
    assert keep_out_clearance_m(inside, scene, 0.25) == pytest.approx(-0.15)
    assert keep_out_clearance_m(path, Scene(keep_in=(), keep_out=()), 0.25) is None


def test_run_figures_and_events_of_a_mission_run():
    row = {"rms_position_error_m": 0.01, "overshoot_m": 0.002, "time_saturated_s": 0.4, "arrival_time_s": None,
           "keep_in_violations": 0, "keep_out_violations": 3, "limit_violations": 1, "keep_out_clearance_m": -0.01}
    metrics = {"rms_position_error_m": 0.03, "violations": {"keep_in": 0, "keep_out": 0, "limits": 0},
               "comparison": {"segment-3/baseline-mpc-prior": row,
                              "segment-3/baseline-tube-prior": {"status": "failed", "error": "x"}},
               "estimate": {"error_pct": [-0.5, 1.0, -2.0, 3.0], "cov_reduction_pct": [99.0, 90.0, 80.0, 70.0]}}
    f = run_figures(metrics)
    assert f["seg3_mpc_prior.arrival_time_s"] == math.inf  # never arrived
    assert f["seg3_mpc_prior.violations"] == 4.0 and f["seg3_mpc_prior.keep_out_clearance_m"] == -0.01
    assert not any(k.startswith("seg3_tube_prior") for k in f)  # a failed flight has no figures
    assert f["batch.abs_error_pct.mass"] == 0.5 and f["batch.cov_reduction_pct.Izz"] == 70.0
    e = run_events("ok", metrics)
    assert e["seg3_mpc_prior.keep_out_entered"] and e["seg3_mpc_prior.never_arrived"] and not e["unsafe"]
