"""Control operations of the dashboard: telemetry snapshots, FoE file list, process-data writes.

Importing this module registers its handlers (``server.HANDLER_MODULES``
lists it). A snapshot is the master's :class:`~pyethercat.master.telemetry.Telemetry`
(taken at most 20 times a second, whoever asks); a process-data write sets
one output entry by name in the image the cyclic loop sends.
"""

from __future__ import annotations

from dataclasses import dataclass

from pyethercat.errors import ConfigError
from pyethercat.master.control.handlers import MasterContext, handler
from pyethercat.master.control.messages import Done
from pyethercat.master.control.protocol import ControlRequest, Reply, request
from pyethercat.master.telemetry import FoeFile, TelemetrySnapshot, telemetry_of

__all__ = ["TelemetryRequest", "FoeFiles", "FoeFileList", "PdoWrite"]


@request("telemetry", TelemetrySnapshot)
@dataclass(frozen=True)
class TelemetryRequest(ControlRequest):
    """A snapshot with the events numbered after ``since``; ``registers``: read the ports too."""

    since: int = 0
    registers: bool = True


@dataclass(frozen=True)
class FoeFileList(Reply):
    files: list[FoeFile]


@request("foe_files", FoeFileList)
@dataclass(frozen=True)
class FoeFiles(ControlRequest):
    """The files moved over FoE through this master (of one slave, or all)."""

    position: int | None = None


@request("pdo_write", Done)
@dataclass(frozen=True)
class PdoWrite(ControlRequest):
    """Set output entry ``name`` of slave ``position`` to ``value`` (range checked)."""

    position: int
    name: str
    value: bool | int | float


@handler(TelemetryRequest)
def _telemetry(ctx: MasterContext, req: TelemetryRequest) -> TelemetrySnapshot:
    ctx.slaves()  # a direct master scans first
    return telemetry_of(ctx.master).snapshot(req.since, registers=req.registers)


@handler(FoeFiles)
def _foe_files(ctx: MasterContext, req: FoeFiles) -> FoeFileList:
    return FoeFileList(telemetry_of(ctx.master).foe_files(req.position))


@handler(PdoWrite)
def _pdo_write(ctx: MasterContext, req: PdoWrite) -> Done:
    s = ctx.slave(req.position)
    cfg = ctx.master.process_data
    sc = cfg.slaves.get(req.position) if cfg is not None else None
    if sc is None:
        raise ConfigError(f"{s.describe()} has no process data configured")
    s.outputs[req.name] = req.value
    return Done()
