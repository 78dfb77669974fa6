"""Diagnostics: the "multiple read" service and the error-counter report.

A "multiple read" (MRD) reads one register from many slaves with one
datagram. The command set of ETG.1000.4 (5.4, the EtherCAT commands) has no
such command, so the intent is served with standard datagrams: one FPRD per slave, all queued at once, so
the scheduler packs them into as few frames as fit (about 100 slaves per
frame for a 2-byte register). Polling states and reading error counters of
a whole segment therefore takes one or two round trips.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass

from pyethercat.master.scheduler import Scheduler
from pyethercat.wire.datagram import Command, Datagram
from pyethercat.wire.registers import (
    ECAT_PROCESSING_ERROR_COUNTER,
    FORWARDED_RX_ERROR_COUNTER,
    LOST_LINK_COUNTER,
    PDI_ERROR_CODE,
    PDI_ERROR_COUNTER,
    RX_ERROR_COUNTER,
)

__all__ = [
    "MultiReadResult",
    "multiple_read",
    "multiple_write",
    "ERROR_COUNTERS_SIZE",
    "PortErrorCounters",
    "SlaveCounters",
    "ErrorCounterReport",
    "decode_error_counters",
    "read_error_counters",
]


@dataclass(frozen=True, slots=True)
class MultiReadResult:
    """What one slave returned: the data and the datagram's working counter."""

    station_address: int
    data: bytes
    wkc: int

    @property
    def ok(self) -> bool:
        """The slave answered (a register read counts 1)."""
        return self.wkc == 1


def multiple_read(scheduler: Scheduler, stations: Sequence[int], address: int, size: int,
                  *, retries: int | None = None) -> list[MultiReadResult]:
    """Read ``size`` bytes at ``address`` from every station, packed into as few frames as fit.

    Results come in the order of ``stations``. A slave that did not answer
    has ``wkc == 0`` (its data is then the zeros that were sent); the caller
    decides whether that is an error. Lost frames are retried and finally
    raise :class:`~pyethercat.errors.TimeoutError`.
    """
    datagrams = [Datagram.device(Command.FPRD, st, address, size) for st in stations]
    replies = scheduler.transact(datagrams, retries=retries)
    return [MultiReadResult(st, bytes(r.data), r.wkc)
            for st, r in zip(stations, replies, strict=True)]


def multiple_write(scheduler: Scheduler, stations: Sequence[int], address: int,
                   data: bytes | Sequence[bytes], *, retries: int | None = None) -> list[int]:
    """Write to ``address`` of every station (same data, or one item per station).

    Returns the working counters in the order of ``stations``.
    """
    if isinstance(data, bytes | bytearray):
        items: Sequence[bytes] = [bytes(data)] * len(stations)
    else:
        items = data
        if len(items) != len(stations):
            raise ValueError(f"{len(items)} data items for {len(stations)} stations")
    datagrams = [Datagram.device(Command.FPWR, st, address, bytes(d))
                 for st, d in zip(stations, items, strict=True)]
    return [r.wkc for r in scheduler.transact(datagrams, retries=retries)]


# --- error counters 0x0300-0x0313 (ET1100 datasheet section II, "Error counters") ----------

#: Bytes from 0x0300 to the end of the lost-link counters.
ERROR_COUNTERS_SIZE = LOST_LINK_COUNTER + 4 - RX_ERROR_COUNTER


@dataclass(frozen=True, slots=True)
class PortErrorCounters:
    """Error counters of one port."""

    invalid_frames: int = 0
    rx_errors: int = 0
    forwarded_rx_errors: int = 0
    lost_links: int = 0

    @property
    def total(self) -> int:
        return self.invalid_frames + self.rx_errors + self.forwarded_rx_errors + self.lost_links


@dataclass(frozen=True, slots=True)
class SlaveCounters:
    """Error counters of one slave (``answered`` False: it did not reply)."""

    position: int
    station_address: int
    ports: tuple[PortErrorCounters, PortErrorCounters, PortErrorCounters, PortErrorCounters]
    processing_unit_errors: int = 0
    pdi_errors: int = 0
    pdi_error_code: int = 0
    answered: bool = True

    @property
    def total(self) -> int:
        return sum(p.total for p in self.ports) + self.processing_unit_errors + self.pdi_errors


def decode_error_counters(position: int, station: int, raw: bytes,
                          answered: bool = True) -> SlaveCounters:
    """Decode the 20 bytes read from 0x0300."""
    if len(raw) < ERROR_COUNTERS_SIZE:
        raw = raw.ljust(ERROR_COUNTERS_SIZE, b"\0")
    base = RX_ERROR_COUNTER
    ports = tuple(
        PortErrorCounters(raw[RX_ERROR_COUNTER + 2 * n - base],
                          raw[RX_ERROR_COUNTER + 2 * n + 1 - base],
                          raw[FORWARDED_RX_ERROR_COUNTER + n - base],
                          raw[LOST_LINK_COUNTER + n - base])
        for n in range(4))
    (code,) = struct.unpack_from("<H", raw, PDI_ERROR_CODE - base)
    return SlaveCounters(position, station, ports,  # type: ignore[arg-type]
                         raw[ECAT_PROCESSING_ERROR_COUNTER - base], raw[PDI_ERROR_COUNTER - base],
                         code, answered)


def read_error_counters(scheduler: Scheduler, slaves: Sequence[tuple[int, int]]
                        ) -> ErrorCounterReport:
    """Error counters of ``slaves`` ((position, station address) each), one multiple read."""
    results = multiple_read(scheduler, [station for _, station in slaves], RX_ERROR_COUNTER,
                            ERROR_COUNTERS_SIZE)
    return ErrorCounterReport(tuple(
        decode_error_counters(position, station, r.data, r.ok)
        for (position, station), r in zip(slaves, results, strict=True)))


@dataclass(frozen=True, slots=True)
class ErrorCounterReport:
    """Error counters of every slave, read in one multiple read."""

    slaves: tuple[SlaveCounters, ...]

    @property
    def total(self) -> int:
        return sum(s.total for s in self.slaves)

    @property
    def with_errors(self) -> list[SlaveCounters]:
        """Slaves with a non-zero counter or no answer."""
        return [s for s in self.slaves if s.total or not s.answered]

    def format(self) -> str:
        """A table: one line per slave; per port invalid/rx/forwarded/lost."""
        lines = ["# pos station  port0 inv/rx/fwd/lost  port1          port2          port3"
                 "          epu  pdi"]
        for s in self.slaves:
            if not s.answered:
                lines.append(f"{s.position:<4} 0x{s.station_address:04X}   no answer")
                continue
            cells = [f"{p.invalid_frames}/{p.rx_errors}/{p.forwarded_rx_errors}/{p.lost_links}"
                     for p in s.ports]
            lines.append(f"{s.position:<4} 0x{s.station_address:04X}   {cells[0]:<21}"
                         f"{cells[1]:<15}{cells[2]:<15}{cells[3]:<15}"
                         f"{s.processing_unit_errors:<5}{s.pdi_errors}")
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.format()
