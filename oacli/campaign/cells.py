"""A campaign's study cells: the product of its ``grid`` factors' levels, and which cell a run flies.

A cell is one combination of levels (``prior=10pct/noise=flight``); its overrides are the levels' overrides,
deep-merged in factor order into the base config before the run's dispersions are drawn. Run ``k`` flies cell
``k mod C`` (``C`` cells) as replicate ``k div C``; the runs of one replicate draw their dispersions, faults and seed
from the replicate's sub-streams, so the cells are compared on the same draws (a paired design). A campaign without a
grid has one unnamed cell and replicate ``k`` is run ``k``.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any

from oacli.config.campaign import CampaignConfig
from oacli.config.mission import deep_merge


@dataclass(frozen=True)
class Cell:
    """One study cell.

    Attributes
    ----------
    name : str
        ``factor=level`` pairs joined by ``/`` (file order).
    levels : dict of str to str
        Factor -> level.
    overrides : dict
        The levels' overrides merged (nested keys).
    """

    name: str
    levels: dict[str, str]
    overrides: dict[str, Any]


def expand_dotted(overrides: dict[str, Any]) -> dict[str, Any]:
    """Nest dotted keys: ``{"mission.prior.mass_kg": 14}`` -> ``{"mission": {"prior": {"mass_kg": 14}}}``.

    Parameters
    ----------
    overrides : dict
        Keys may contain dots (a path) or not; nested mappings are expanded too.

    Returns
    -------
    dict
    """
    out: dict[str, Any] = {}
    for key, value in overrides.items():
        value = expand_dotted(value) if isinstance(value, dict) else value
        parts = str(key).split(".")
        for part in reversed(parts[1:]):
            value = {part: value}
        out = deep_merge(out, {parts[0]: value})
    return out


def campaign_cells(cfg: CampaignConfig) -> tuple[Cell, ...]:
    """The cells of ``cfg.grid`` in product order (empty without a grid).

    Parameters
    ----------
    cfg : CampaignConfig

    Returns
    -------
    tuple of Cell
    """
    if not cfg.grid:
        return ()
    factors = list(cfg.grid.items())
    cells = []
    for combo in itertools.product(*(list(levels.items()) for _, levels in factors)):
        merged: dict[str, Any] = {}
        for _, (_, overrides) in zip(factors, combo, strict=True):
            merged = deep_merge(merged, expand_dotted(overrides))
        levels = {factor: level for (factor, _), (level, _) in zip(factors, combo, strict=True)}
        cells.append(Cell("/".join(f"{f}={lv}" for f, lv in levels.items()), levels, merged))
    return tuple(cells)


def cell_and_replicate(cfg: CampaignConfig, k: int) -> tuple[Cell | None, int]:
    """The cell run ``k`` flies and its replicate index (module docstring).

    Parameters
    ----------
    cfg : CampaignConfig
    k : int
        Run index.

    Returns
    -------
    cell : Cell or None
        None without a grid.
    replicate : int
        ``k div C`` (``k`` without a grid): the index of the run's draws.
    """
    cells = campaign_cells(cfg)
    if not cells:
        return None, int(k)
    return cells[int(k) % len(cells)], int(k) // len(cells)


__all__ = ["Cell", "campaign_cells", "cell_and_replicate", "expand_dotted"]
