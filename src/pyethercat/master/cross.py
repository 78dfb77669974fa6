"""Cross traffic: one slave's inputs become a later slave's outputs within one frame.

EtherCAT slaves exchange data with each other through the logical process
image: when a slave's input FMMU (it writes into the frame) and a later
slave's output FMMU (it takes from the frame) map the same logical bits,
the data flows from the first to the second as the frame passes them, in
the same cycle and without the master copying it (the FMMU overlap rules:
a logical byte may be written by one slave and read by another; ESC
datasheet section I, "Fieldbus Memory Management Unit"). The slave that
produces must come first on the frame's way: a consumer before its
producer would see the data of the cycle before at best.

:class:`CrossLink` names a producer and a consumer (ring positions) and
which of their bits are joined; :func:`apply_cross_traffic` moves the
consumer's output FMMU onto the producer's input bits in a computed
configuration and recomputes the working counters the datagrams expect (the
consumer now counts where the producer's inputs are). The consumer's output
variables in the master's image then have no effect: its outputs come from
the producer.

On a ring the frames of a group with cross traffic go out on one port and
on through the other (``CyclicTemplate.ordered``), so a producer and a
consumer on the two sides of a broken cable still meet in one frame.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

from pyethercat.errors import ConfigError
from pyethercat.esi.eni import EniSlave
from pyethercat.master.config import (
    CrossLink,
    PdoDirection,
    ProcessDataConfig,
    SlaveConfig,
    expected_wkc,
)
from pyethercat.wire import registers as reg

__all__ = ["CrossLink", "apply_cross_traffic", "cross_links_from_eni"]


def apply_cross_traffic(cfg: ProcessDataConfig, links: Sequence[CrossLink]) -> ProcessDataConfig:
    """Move each consumer's output FMMU onto its producer's input bits (in place; returned)."""
    for link in links:
        prod, cons = _slave(cfg, link.producer, "producer"), _slave(cfg, link.consumer, "consumer")
        where = f"cross traffic slave {link.producer} -> slave {link.consumer}"
        if prod.group != cons.group or not prod.group:
            raise ConfigError(f"{where}: both slaves must be in one process-data group")
        if link.producer >= link.consumer:
            raise ConfigError(f"{where}: the producer must come before the consumer on the "
                              "frame's way (a lower ring position)")
        bits = cons.output_bits - link.consumer_bit if link.bits is None else link.bits
        if bits <= 0 or link.consumer_bit < 0 or link.producer_bit < 0:
            raise ConfigError(f"{where}: nothing to join ({bits} bits)")
        if prod.input_bit_offset < 0 or link.producer_bit + bits > prod.input_bits:
            raise ConfigError(f"{where}: slave {link.producer} has {prod.input_bits} input bits, "
                              f"{link.producer_bit + bits} asked for")
        if link.consumer_bit + bits > cons.output_bits:
            raise ConfigError(f"{where}: slave {link.consumer} has {cons.output_bits} output "
                              f"bits, {link.consumer_bit + bits} asked for")
        old = next((f for f in cons.fmmus if f.fmmu_type & reg.FmmuType.WRITE), None)
        if old is None:
            raise ConfigError(f"{where}: slave {link.consumer} has no output FMMU")
        group = cfg.group(prod.group)
        first = prod.input_bit_offset + link.producer_bit
        last = first + bits - 1
        phys_bit = old.physical_start_bit + link.consumer_bit
        new = dataclasses.replace(
            old, logical_start=group.logical_base + first // 8,
            length=last // 8 - first // 8 + 1, logical_start_bit=first % 8,
            logical_stop_bit=last % 8, physical_start=old.physical_start + phys_bit // 8,
            physical_start_bit=phys_bit % 8)
        cons.fmmus[cons.fmmus.index(old)] = new
        if link.consumer_bit == 0 and bits == cons.output_bits:
            # Its output variables now show what the producer sends it.
            shift = first - cons.output_bit_offset
            cons.variables = [dataclasses.replace(v, bit_offset=v.bit_offset + shift)
                              if v.direction is PdoDirection.OUTPUTS else v
                              for v in cons.variables]
            cons.output_bit_offset = first
        group.cross = (*group.cross, link)
    for group in cfg.groups:
        if not group.cross:
            continue
        fmmus = [(s.position, f) for s in group.slaves for f in s.fmmus]
        out = []
        for d in group.datagrams:
            wkc, who = expected_wkc(d.command, d.logical_address, d.logical_address + d.length,
                                    fmmus)
            out.append(dataclasses.replace(d, expected_wkc=wkc, positions=who))
        group.datagrams = out
    return cfg


def cross_links_from_eni(slaves: Sequence[EniSlave]) -> list[CrossLink]:
    """Cross traffic an ENI describes: a slave's outputs (``Send``) lying inside another's
    inputs (``Recv``) in the process image, as :func:`apply_cross_traffic` leaves them."""
    links = []
    for c in slaves:
        if c.send_bit_start is None or not c.send_bit_length:
            continue
        for p in slaves:
            if p is c or p.recv_bit_start is None:
                continue
            lo, hi = p.recv_bit_start, p.recv_bit_start + p.recv_bit_length
            if lo <= c.send_bit_start and c.send_bit_start + c.send_bit_length <= hi:
                links.append(CrossLink(p.position, c.position, c.send_bit_length,
                                       c.send_bit_start - lo))
                break
    return links


def _slave(cfg: ProcessDataConfig, position: int, role: str) -> SlaveConfig:
    try:
        return cfg.slaves[position]
    except KeyError:
        raise ConfigError(f"cross traffic: no slave {position} (the {role})") from None

