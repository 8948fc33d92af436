"""The study presets (``configs/study_*.yaml``, issue 34): their cells and seed counts, the fourth segment-3 flight
(the paper's standard MPC without workspace constraints, flown in the same mission), every Fig. 3(d) cell's mission
deriving all its stage configs, and the RATTLE preset's RLS figures in the per-cell statistics."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from oacli.campaign.aggregate import run_figures
from oacli.campaign.cells import campaign_cells
from oacli.campaign.driver import load_campaign, write_specs
from oacli.campaign.sampling import sample_run
from oacli.config import ConfigError, config_from_dict
from oacli.config.overrides import apply_overrides
from oacli.mission.configs import Handoff, stage_config
from oacli.mission.layout import UNCONSTRAINED_BASELINE, stage_by_key
from oacli.mission.run import mission_stages, validate_mission

ROOT = Path(__file__).resolve().parents[1]


def _mission(*sets: str):
    data = apply_overrides(yaml.safe_load((ROOT / "configs" / "mission_iss.yaml").read_text()), list(sets))
    return config_from_dict(data, source="test")


def test_the_unconstrained_standard_mpc_is_flown_only_when_asked():
    keys = [s.key for s in mission_stages(_mission())]
    assert UNCONSTRAINED_BASELINE not in keys and "segment-3/baseline-mpc-prior" in keys
    keys = [s.key for s in mission_stages(_mission("mission.unconstrained_baseline=true"))]
    assert keys[-1] == UNCONSTRAINED_BASELINE
    keys = [s.key for s in mission_stages(_mission("mission.unconstrained_baseline=true", "mission.baselines=false"))]
    assert not any("baseline" in k for k in keys)


def test_the_unconstrained_flight_is_the_constrained_one_without_workspace_rows():
    cfg = _mission("mission.unconstrained_baseline=true")
    handoff = Handoff(reference=Path("r.mcap"))
    free = stage_config(cfg, stage_by_key(UNCONSTRAINED_BASELINE), handoff)
    kept = stage_config(cfg, stage_by_key("segment-3/baseline-mpc-prior"), handoff)
    assert free.controller.type == kept.controller.type == "mpc"
    assert kept.controller.position_constraints and not free.controller.position_constraints
    assert free.robot.mass_kg == kept.robot.mass_kg == cfg.mission.prior.mass_kg  # the prior's model, both
    assert free.reference == kept.reference and free.truth == kept.truth  # the same plan, the same plant
    # everything else equal (the seed aside: each stage draws its own noise)
    a, b = free.model_dump(mode="json"), kept.model_dump(mode="json")
    for d in (a, b):
        d.pop("seed"), d.pop("name"), d["controller"].pop("position_constraints")
    assert a == b


def test_fig3d_preset_is_8_cells_of_50_seeds_and_every_cells_mission_derives():
    campaign = load_campaign(ROOT / "configs" / "study_fig3d.yaml")
    cells = campaign_cells(campaign.config)
    assert len(cells) == 8 and campaign.config.runs == 50 * len(cells)
    for k, cell in enumerate(cells):  # run k flies cell k: each cell's whole mission derives (the ideal-sensor
        spec = sample_run(campaign.config, campaign.base, k)  # cells failed at segment 2 before: tube observer)
        assert spec["cell"] == cell.name
        cfg = config_from_dict(spec["config"], source=cell.name)
        validate_mission(cfg)
        assert UNCONSTRAINED_BASELINE in [s.key for s in mission_stages(cfg)]


def test_a_cell_whose_mission_cannot_derive_stops_the_campaign_before_any_run(tmp_path):
    campaign = load_campaign(ROOT / "configs" / "study_fig3d.yaml",
                             ["grid.sensors.ideal.controller.tube.observer.enabled=true", "runs=8"])
    with pytest.raises(ConfigError, match=r"run 0 \(cell prior_error=0pct/sensors=ideal\).*observer"):
        write_specs(campaign, tmp_path)
    assert not (tmp_path / "runs.json").exists()


def test_rattle_and_expset3_presets_have_50_seeds_per_cell():
    rattle = load_campaign(ROOT / "configs" / "study_rattle.yaml")
    assert rattle.config.job == "excite-estimate" and rattle.config.runs == 50 and not rattle.config.grid
    assert rattle.base["estimation"]["method"] == "rls" and rattle.base["excitation"]["method"] == "rattle"
    expset3 = load_campaign(ROOT / "configs" / "study_expset3.yaml")
    assert expset3.config.runs == 50 * len(campaign_cells(expset3.config)) == 100


def test_an_rls_estimate_is_reported_under_its_own_name():
    metrics = {"estimate": {"method": "rls", "error_pct": [-0.4, 0.9, -1.3, 6.9],
                            "cov_reduction_pct": [99.0, 68.0, 49.0, 25.0]}}
    f = run_figures(metrics)
    assert f["rls.abs_error_pct.mass"] == 0.4 and f["rls.cov_reduction_pct.Izz"] == 25.0
    assert not any(k.startswith("batch.") for k in f)


def test_overshoot_is_measured_along_the_final_approach_not_the_last_velocity():
    """A reference along -y that passes its goal by 10 mm and ends with a correction in +y (as some smoothed
    segment-3 plans do): a flight following it overshoots 10 mm; along the last velocity the whole route read as
    1.4 m past the goal."""
    import numpy as np

    from oacli.mission.compare import approach_direction, overshoot_m

    y = np.concatenate([np.linspace(0.0, -1.41, 200), [-1.405, -1.4]])  # ends moving +y by 5 mm
    ref = np.column_stack([np.zeros_like(y), y, np.zeros_like(y)])
    goal = ref[-1]
    flown = ref.copy()
    flown[-1, 1] = -1.405                                                 # stops 5 mm past the goal
    last_velocity = ref[-1] - ref[-2]
    t = np.arange(len(y), dtype=float)
    assert overshoot_m(t, flown, goal, last_velocity) > 1.3             # the former reading
    np.testing.assert_allclose(approach_direction(ref) / np.linalg.norm(approach_direction(ref)), [0, -1, 0])
    assert overshoot_m(t, flown, goal, approach_direction(ref)) == pytest.approx(0.01)
