"""What a stage writes besides its MCAP, its Rerun recording and its summary (``outputs``)."""

from __future__ import annotations

from pydantic import Field

from oacli.config.fields import Section


class OutputsConfig(Section):
    """Optional outputs of every stage and of the mission."""

    plots: bool = Field(
        default=True,
        description="Write the PNG figures (matplotlib, Agg) of each stage and of the mission (default true). "
        "false skips them, e.g. in campaigns and benchmarks: the MCAP and the .rrd hold the same data.",
    )
