"""MCAP I/O facade: the writer (:mod:`oacli.io.mcap_write`) and the readers (:mod:`oacli.io.mcap_read`)."""

from oacli.io.mcap_read import StageRecord, read_stage, read_telemetry, read_trajectory
from oacli.io.mcap_write import DEFAULT_CHUNK_SIZE, StageMcapWriter

__all__ = [
    "DEFAULT_CHUNK_SIZE",
    "StageMcapWriter",
    "StageRecord",
    "read_stage",
    "read_telemetry",
    "read_trajectory",
]
