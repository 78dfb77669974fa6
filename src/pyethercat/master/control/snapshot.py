"""Slaves across the control socket: a snapshot of the registers and SII, and the rebuild.

The running master sends what its scan read (identification registers, DL
and AL status, the SII image); the client rebuilds
:class:`~pyethercat.master.slave.Slave` objects with the scan's own
functions, so every listing (``slaves -v``, ``graph``, ``cstruct``) is made
by the same code for a running master and for direct access.
"""

from __future__ import annotations

from collections.abc import Sequence

from pyethercat.master.control.messages import SlaveSnapshot
from pyethercat.master.scan import apply_sii, build_topology
from pyethercat.master.slave import Port, Slave
from pyethercat.wire.al import AlState

__all__ = ["snapshot", "rebuild"]


def snapshot(slave: Slave) -> SlaveSnapshot:
    """What a client needs to rebuild ``slave``."""
    return SlaveSnapshot(
        position=slave.position, station_address=slave.station_address, alias=slave.alias,
        esc=slave.esc, esc_config=slave.esc_config, dl_status=slave.dl_status,
        al_state=int(slave.al_state), al_error=slave.al_error,
        al_status_code=slave.al_status_code, sii_read_8=slave.sii_read_8,
        sii_image=slave.sii_image, sii_error=slave.sii_error)


def rebuild(items: Sequence[SlaveSnapshot]) -> tuple[list[Slave], bool]:
    """Slave objects (with SII, ports and topology) and whether the topology is consistent."""
    slaves: list[Slave] = []
    for it in items:
        s = Slave(it.position, it.station_address)
        s.esc = it.esc
        s.esc_config = it.esc_config
        s.dl_status = it.dl_status
        try:
            s.al_state = AlState(it.al_state)
        except ValueError:
            s.al_state = AlState.NONE
        s.al_error = it.al_error
        s.al_status_code = it.al_status_code
        s.sii_read_8 = it.sii_read_8
        s.ports = [Port.from_registers(p, it.esc.port_descriptor, it.dl_status) for p in range(4)]
        if it.sii_image and it.sii_error is None:
            apply_sii(s, it.sii_image)
        else:
            s.sii_image = it.sii_image
            s.sii_error = it.sii_error
        # The register value the master read wins over the SII word (apply_sii fills in).
        s.alias = it.alias
        if not s.name:
            s.name = "?"
        slaves.append(s)
    return slaves, build_topology(slaves)
