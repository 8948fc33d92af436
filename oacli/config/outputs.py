"""What a stage writes besides its MCAP, its Rerun recording and its summary (``outputs``)."""

from __future__ import annotations

from enum import StrEnum
from typing import Annotated, Any

from pydantic import BeforeValidator, Field, StrictBool
from pydantic_core import PydanticCustomError

from oacli.config.fields import Section


class PlotSet(StrEnum):
    """Which PNG figures a run draws (``outputs.plots``).

    * ``all`` -- every stage's own PNGs (in its folder) and, in a mission, the mission's (``plots/``);
    * ``mission`` -- the mission's PNGs only; a stage draws none of its own (its data stays in its MCAP and its
      ``.rrd``; ``oacli plots RUN_DIR`` draws them afterwards);
    * ``none`` -- no PNG at all.

    A member is true in a boolean context exactly when a *stage* draws its own PNGs (``all``), so a stage's
    ``if cfg.outputs.plots:`` reads "draw this stage's figures" (:attr:`OutputsConfig.stage_pngs` says it by
    name).
    """

    ALL = "all"
    MISSION = "mission"
    NONE = "none"

    def __bool__(self) -> bool:
        return self is PlotSet.ALL


def _plot_set(value: Any) -> Any:
    """``true``/``false`` (the old boolean form, also as text from ``--set``) -> ``all``/``none``; other text is
    matched case-insensitively."""
    if isinstance(value, bool):
        return PlotSet.ALL if value else PlotSet.NONE
    if isinstance(value, str):
        text = value.strip().lower()
        text = {"true": "all", "false": "none", "yes": "all", "no": "none"}.get(text, text)
        if text not in {p.value for p in PlotSet}:
            raise PydanticCustomError("oacli_plots", "must be one of all, mission, none (or true = all, false = none)")
        return PlotSet(text)
    if isinstance(value, PlotSet):
        return value
    raise PydanticCustomError("oacli_plots", "must be one of all, mission, none (or true = all, false = none)")


class OutputsConfig(Section):
    """Optional outputs of every stage and of the mission."""

    plots: Annotated[PlotSet, BeforeValidator(_plot_set)] = Field(
        default=PlotSet.ALL,
        description="Which PNG figures (matplotlib, Agg) to write: 'all' (default: each stage's own, and in a "
        "mission also the mission's plots/), 'mission' (the mission's plots/ only; the stages' data stays in their "
        "MCAP and .rrd, and 'oacli plots RUN_DIR' draws their PNGs afterwards), 'none' (no PNG, e.g. in campaigns "
        "and benchmarks). true and false still mean all and none.",
    )

    report: StrictBool = Field(
        default=True,
        description="oacli mission: write report.html (one self-contained offline page: status, segments, figures, "
        "config; 'oacli report RUN_DIR' writes it afterwards). false: no report.",
    )

    @property
    def stage_pngs(self) -> bool:
        """Whether a stage draws its own PNGs (``all``)."""
        return _plot_set(self.plots) is PlotSet.ALL  # also a bare bool set by model_copy (no validation)

    @property
    def mission_pngs(self) -> bool:
        """Whether a mission draws its own PNGs into ``plots/`` (``all`` or ``mission``)."""
        return _plot_set(self.plots) is not PlotSet.NONE


class CampaignOutputsConfig(Section):
    """Optional outputs of a campaign (the campaign file's ``outputs``)."""

    report: StrictBool = Field(
        default=True,
        description="Write report.html in the campaign folder (statistics, per-cell intervals, CDFs, one row per run "
        "with its rerun command; 'oacli report DIR' writes it afterwards). false: no report.",
    )


__all__ = ["CampaignOutputsConfig", "OutputsConfig", "PlotSet"]
