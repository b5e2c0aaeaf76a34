"""The ``[execution]`` table: where and how a campaign's cases run (never part of the configuration hash)."""
from __future__ import annotations

from dask.utils import parse_bytes
from pydantic import Field, field_validator

from flight_interface.tomlfields import ConfigModel, FieldProblem

SCHEDULER_SCHEMES = ("tcp://", "tls://", "inproc://")
MIN_MEMORY_LIMIT_BYTES = 2**20


class ExecutionConfig(ConfigModel):
    """``[execution]``: the dask cluster a campaign runs on (command-line flags override it)."""

    scheduler: str = ""
    """"" = an embedded LocalCluster, or the address of an existing scheduler ("tcp://host:port")."""
    workers: int = Field(0, ge=0, le=1024)
    """Worker processes of the embedded cluster (0 = one per core)."""
    retries: int = Field(1, ge=0, le=10)
    """Attempts after the first for a case whose computation raises."""
    memory_limit: str = "1.5GiB"
    """Memory limit per worker of the embedded cluster, e.g. "1.5GiB", "800MiB"."""

    @field_validator("scheduler")
    @classmethod
    def _address(cls, value: str) -> str:
        if value and not value.startswith(SCHEDULER_SCHEMES):
            raise FieldProblem("", f"= {value!r} is not a scheduler address; allowed: \"\" (embedded) or "
                               "tcp://host:port")
        return value

    @field_validator("memory_limit")
    @classmethod
    def _memory_size(cls, value: str) -> str:
        try:
            size = parse_bytes(value) if value.strip() else 0
        except (ValueError, TypeError, OverflowError):
            size = 0
        if size < MIN_MEMORY_LIMIT_BYTES:
            raise FieldProblem("", f"= {value!r} is not a memory size; allowed: e.g. \"1.5GiB\", \"800MiB\", "
                               "\"2GB\" (>= 1 MiB)")
        return value

    @property
    def memory_limit_bytes(self) -> int:
        return parse_bytes(self.memory_limit)
