"""Control operations on CiA 402 drives: ``pyethercat drive`` (status, enable, moves, homing).

Importing this module registers its handler (``server.HANDLER_MODULES`` lists
it; the command line imports it for its own short-lived master).

``status`` works on any master: from the process image when the drive's
statusword is mapped and cycling, else by SDO. Every other action drives the
drive through a :class:`~pyethercat.master.cia402.DriveGroup` on the running
master's cycle (its controlword must be mapped), so it needs a master that
exchanges process data: ``pyethercat run`` in another terminal, or a program
that started one.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from pyethercat.errors import ConfigError, EtherCATError
from pyethercat.master.cia402 import DriveGroup
from pyethercat.master.control.handlers import MasterContext, handler
from pyethercat.master.control.protocol import ControlRequest, Reply, request
from pyethercat.wire.cia402 import DriveState, OperationMode, decode_state, parse_mode
from pyethercat.wire.mailbox.coe import emergency_error_name
from pyethercat.wire.mailbox.objects import Cia402Object

__all__ = ["DRIVE_ACTIONS", "DriveAction", "DriveReply", "DriveStatus"]

#: What ``pyethercat drive`` can do.
DRIVE_ACTIONS = ("status", "enable", "disable", "reset", "quickstop", "mode", "move", "home")
_O = Cia402Object


@dataclass(frozen=True)
class DriveStatus:
    """One drive as its objects show it."""

    position: int
    statusword: int
    state: str
    mode: str
    actual_position: int | None
    following_error: int | None
    error_code: int
    error_text: str
    warning: bool


@dataclass(frozen=True)
class DriveReply(Reply):
    """The drives after the action; ``source`` says where the values came from."""

    drives: list[DriveStatus] = field(default_factory=list)
    source: str = "sdo"


@request("drive", DriveReply)
@dataclass(frozen=True)
class DriveAction(ControlRequest):
    """One action on the drives at ``positions`` (see :data:`DRIVE_ACTIONS`).

    ``positions`` None: every drive of the segment (other slaves are left out).
    """

    action: str
    positions: list[int] | None
    mode: str | None = None
    target: int | None = None
    relative: bool = False
    velocity: int | None = None
    acceleration: int | None = None
    method: int | None = None
    timeout: float = 5.0


@handler(DriveAction)
def _drive(ctx: MasterContext, req: DriveAction) -> DriveReply:
    if req.action not in DRIVE_ACTIONS:
        raise ConfigError(f"unknown drive action {req.action!r}: one of {', '.join(DRIVE_ACTIONS)}")
    chosen = req.positions is not None
    slaves = ctx.select(req.positions)
    positions = [s.position for s in slaves]
    runner = ctx.runner
    group = None
    if runner is not None:
        try:
            group = DriveGroup(ctx.master, positions if chosen else None)
        except ConfigError:
            if req.action != "status":
                raise
    if group is None:
        if req.action != "status":
            raise ConfigError(f"drive {req.action} needs a master that exchanges process data with "
                              "the drive (start one with 'pyethercat run', then repeat)")
        if chosen:
            return DriveReply([_by_sdo(ctx, p) for p in positions], "sdo")
        found = []
        for p in positions:
            try:
                found.append(_by_sdo(ctx, p))
            except ConfigError:  # not a drive (no CoE, no statusword 0x6041)
                continue
        if not found:
            raise ConfigError("no CiA 402 drive on the segment (no slave has a statusword 0x6041)")
        return DriveReply(found, "sdo")
    group.attach(runner)
    try:
        _act(group, req)
        return DriveReply(_from_group(ctx, group), "process data")
    finally:
        group.detach()


def _act(group: DriveGroup, req: DriveAction) -> None:
    t = req.timeout
    if req.action == "enable":
        group.enable(t)
    elif req.action == "disable":
        group.disable(t)
    elif req.action == "reset":
        group.fault_reset(t)
    elif req.action == "quickstop":
        group.quick_stop(t)
    elif req.action == "mode":
        if req.mode is None:
            raise ConfigError("drive mode needs a mode: pp, pv, hm, csp, csv, cst (or 1-10)")
        group.set_mode(parse_mode(req.mode), t)
    elif req.action == "move":
        if req.target is None:
            raise ConfigError("drive move needs a target position")
        group.move_to(req.target, velocity=req.velocity, acceleration=req.acceleration,
                      deceleration=req.acceleration, relative=req.relative, timeout=t)
    elif req.action == "home":
        group.home(req.method, t)


def _mode_name(value: int) -> str:
    try:
        return OperationMode(value).short
    except ValueError:
        return str(value)


def _status(position: int, sw: int, mode: int, actual: int | None, fe: int | None,
            error: int) -> DriveStatus:
    state = decode_state(sw)
    return DriveStatus(position, sw, state.label if state is not None else "undefined",
                       _mode_name(mode), actual, fe, error,
                       emergency_error_name(error) if error else "", bool(sw & 0x80))


def _by_sdo(ctx: MasterContext, position: int) -> DriveStatus:
    s = ctx.slave(position)
    ctx.coe(position, "CoE: not a CiA 402 drive")

    def read(index: int, kind: str) -> int | None:
        try:
            return int(s.sdo_read(index, 0, kind))
        except EtherCATError:
            return None

    sw = read(int(_O.STATUSWORD), "uint16")
    if sw is None:
        raise ConfigError(f"slave {position} has no statusword 0x6041: not a CiA 402 drive")
    return _status(position, sw, read(int(_O.MODES_OF_OPERATION_DISPLAY), "int8") or 0,
                   read(int(_O.POSITION_ACTUAL_VALUE), "int32"),
                   read(int(_O.FOLLOWING_ERROR_ACTUAL_VALUE), "int32"),
                   read(int(_O.ERROR_CODE), "uint16") or 0)


def _sdo_int(ctx: MasterContext, position: int, index: int, kind: str) -> int | None:
    try:
        return int(ctx.slave(position).sdo_read(int(index), 0, kind))
    except EtherCATError:
        return None


def _from_group(ctx: MasterContext, group: DriveGroup) -> list[DriveStatus]:
    sws = group.statuswords()
    modes = group.modes()
    try:
        actual: list[int | None] = [int(v) for v in group.positions_actual()]
    except ConfigError:  # not in the PDOs: by SDO
        actual = [_sdo_int(ctx, p, _O.POSITION_ACTUAL_VALUE, "int32") for p in group.positions]
    try:
        fes: list[int | None] = [int(v) for v in group.following_errors()]
    except ConfigError:
        fes = [_sdo_int(ctx, p, _O.FOLLOWING_ERROR_ACTUAL_VALUE, "int32") for p in group.positions]
    out = []
    for i, p in enumerate(group.positions):
        error = 0
        state = decode_state(int(sws[i]))
        if state in (DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE):
            error = int(ctx.slave(p).sdo_read(int(_O.ERROR_CODE), 0, "uint16"))
        out.append(_status(p, int(sws[i]), int(modes[i]), actual[i], fes[i], error))
    return out
