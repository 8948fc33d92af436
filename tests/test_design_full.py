"""The offline excitation design for chosen entries of the full rigid body (oacli.excitation.design_full)."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from oacli.excitation.design import ScpSettings, design_excitation
from oacli.excitation.design_full import FullScpMerit, symmetric_pairs
from oacli.excitation.design_types import FullDesignSpec
from oacli.excitation.fim_gradient import SYMMETRIC_PAIRS
from oacli.excitation.information_full import ideal_theta, information_summary
from tests.test_excitation_design import THETA, problem

PRIOR_STD = np.r_[np.sqrt([15.0, 0.005, 0.005, 0.005]), np.full(3, 0.005), np.full(3, 0.01), np.full(6, 0.05)]
GROUPS = ("mass", "inertia", "products", "com")


def test_pairs_extend_the_four_entry_order() -> None:
    assert symmetric_pairs(4) == tuple(SYMMETRIC_PAIRS)
    assert len(symmetric_pairs(10)) == 55
    with pytest.raises(ValueError, match="A-criterion"):
        FullScpMerit(problem(criterion="D"), 10.0, FullDesignSpec(GROUPS, ideal_theta(THETA), PRIOR_STD))


def test_full_design_informs_products_and_com_better_than_the_four_entry_design() -> None:
    base = problem(n=30, duration=30.0)
    full = dataclasses.replace(base, information=FullDesignSpec(GROUPS, ideal_theta(THETA), PRIOR_STD))
    design = design_excitation(full, ScpSettings(max_iterations=10))
    legacy = design_excitation(base, ScpSettings(max_iterations=10))
    # The merit never grows, the design ends at the goal at rest and within the limits.
    merits = [it.merit for it in design.iterations]
    assert all(b <= a for a, b in itertools.pairwise(merits))
    assert sum(design.violations.values()) == 0.0, design.violations
    assert design.collision_free
    assert design.criterion_final < 0.5 * design.criterion_initial
    # The criterion is the scaled A-criterion of the chosen entries along the design (prior of the extras added).
    s_full = information_summary(full.start, design.trajectory.u[:-1], ideal_theta(THETA), full.dt,
                                 full.measurement, GROUPS, PRIOR_STD)
    assert design.criterion_final == pytest.approx(s_full["a_criterion"], rel=1e-9)
    s_legacy = information_summary(base.start, legacy.trajectory.u[:-1], ideal_theta(THETA), base.dt,
                                   base.measurement, GROUPS, PRIOR_STD)
    assert s_full["a_criterion"] < 0.7 * s_legacy["a_criterion"]
    products = [f"I{a}_kgm2" for a in ("xy", "xz", "yz")]
    assert sum(s_full["crb_over_prior"][k] for k in products) < sum(s_legacy["crb_over_prior"][k] for k in products)
    # The outputs stay the 4 entries' information of the design.
    assert design.fim.shape == (4, 4) and design.crb_std.shape == (4,)


def test_config_refuses_bad_information_choices(tmp_path) -> None:
    from pydantic import ValidationError
    from typer.testing import CliRunner

    from oacli.cli import app
    from oacli.config.excitation import ExcitationConfig
    from tests.conftest import REPO

    assert ExcitationConfig().information.is_legacy
    with pytest.raises(ValidationError, match=r"information\.parameters"):
        ExcitationConfig(information={"parameters": ["mass", "com"]})
    with pytest.raises(ValidationError, match=r"information\.parameters"):
        ExcitationConfig(information={"parameters": ["mass", "inertia", "spin"]})
    result = CliRunner().invoke(app, ["excite", str(REPO / "configs" / "iss_reswarm.yaml"), "--out",
                                      str(tmp_path / "x"), "--quiet", "--set", "excitation.criterion=D", "--set",
                                      "excitation.information.parameters=[mass,inertia,com]"])
    assert result.exit_code == 2, result.output
    assert "excitation.information.parameters" in result.output and "A-criterion" in result.output
    assert "Traceback" not in result.output
    result = CliRunner().invoke(app, ["excite", str(REPO / "configs" / "iss_reswarm.yaml"), "--method", "rattle",
                                      "--out", str(tmp_path / "y"), "--quiet", "--set",
                                      "excitation.information.parameters=[mass,inertia,products]"])
    assert result.exit_code == 2, result.output
    assert "excitation.information.parameters" in result.output and "products not in estimation.parameters" in (
        result.output)
    assert not (tmp_path / "y").exists() and not (tmp_path / "x").exists()  # refused before any run folder
