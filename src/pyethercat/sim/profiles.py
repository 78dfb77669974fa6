"""ESC profiles: chip families with their resources (issue 3 item 1).

A profile says what a slave controller has: identity register values, how
many FMMUs and sync managers, how much process RAM, which ports, which
features. The ESC model derives from it which register bytes exist (reads
and writes of bytes a chip lacks are answered with working counter 0) and
which bytes the EtherCAT side may write.

Values follow the public descriptions of the chips (Beckhoff ET1100/ET1200,
Microchip LAN9252, an FPGA IP core); where a value was not found in a public
source it is a plausible default and can be overridden per device with
:meth:`EscProfile.replace`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from pyethercat.wire.registers import Feature, PortType

# Real EK1100/EL2828/EL2889/EL2004 (corpus captures) read 0x0008 = 0x00FC.
_DC_FULL = (Feature.DC_SUPPORTED | Feature.DC_64BIT | Feature.LOW_JITTER_EBUS
            | Feature.ENHANCED_LINK_EBUS | Feature.ENHANCED_LINK_MII
            | Feature.SEPARATE_FCS_ERRORS)


@dataclass(frozen=True)
class EscProfile:
    """Resources and identity of one ESC family.

    ``ports`` gives the type of ports 0-3 (``PortType.NOT_IMPLEMENTED`` for a
    port the chip does not have). ``sii_read_bytes`` is 4 or 8: how many bytes
    one SII read command fetches (0x0502 bit 6 reports 8). ``forwarding_delay_ns``
    is the delay a frame needs to pass the chip once (None: from the port
    types, about 500 ns for MII and 100 ns for E-Bus, seed 004).
    """

    name: str
    esc_type: int
    revision: int
    build: int
    fmmu_count: int
    sm_count: int
    ram_kib: int
    ports: tuple[PortType, PortType, PortType, PortType]
    features: int
    sii_read_bytes: int = 8
    forwarding_delay_ns: int | None = None
    #: Extra static bits of SII control 0x0502 some chips show (e.g. the
    #: EL2828 in the corpus reads bit 4 = 0x0010, meaning not documented).
    sii_control_static: int = 0

    def replace(self, **changes: object) -> EscProfile:
        """A copy with some fields changed (e.g. ports of a particular board)."""
        return dataclasses.replace(self, **changes)  # type: ignore[arg-type]

    @property
    def port_descriptor(self) -> int:
        """Value of register 0x0007 (two bits per port)."""
        value = 0
        for n, ptype in enumerate(self.ports):
            value |= (int(ptype) & 3) << (2 * n)
        return value

    @property
    def implemented_ports(self) -> tuple[int, ...]:
        """Port numbers the chip has."""
        return tuple(n for n, p in enumerate(self.ports)
                     if p not in (PortType.NOT_IMPLEMENTED, PortType.NOT_CONFIGURED))

    @property
    def ram_end(self) -> int:
        """First address after the process RAM."""
        return min(0x1000 + self.ram_kib * 1024, 0x10000)

    @property
    def dc_supported(self) -> bool:
        return bool(self.features & Feature.DC_SUPPORTED)

    @property
    def dc_64bit(self) -> bool:
        return bool(self.features & Feature.DC_64BIT)

    @property
    def default_forwarding_delay_ns(self) -> int:
        """Forwarding delay through this chip (explicit, else from the port types)."""
        if self.forwarding_delay_ns is not None:
            return self.forwarding_delay_ns
        if any(p == PortType.MII for p in self.ports):
            return 500
        return 100


_MII, _EBUS, _NONE = PortType.MII, PortType.EBUS, PortType.NOT_IMPLEMENTED

PROFILES: dict[str, EscProfile] = {
    # Beckhoff ET1100: 4 ports, 8 FMMU, 8 SM, 8 KiB, 64-bit DC (EK1100 uses
    # MII on port 0 and 3 and E-Bus on 1; port 2 unused by the coupler).
    "ET1100": EscProfile("ET1100", 0x11, 0x00, 0x0002, 8, 8, 8,
                         (_MII, _EBUS, _EBUS, _MII), int(_DC_FULL)),
    # Beckhoff ET1200: 3 ports (E-Bus terminals use 0 and 1), 3 FMMU, 4 SM, 1 KiB.
    "ET1200": EscProfile("ET1200", 0x12, 0x00, 0x0001, 3, 4, 1,
                         (_EBUS, _EBUS, _NONE, _NONE), int(_DC_FULL)),
    # Microchip LAN9252: 2 MII ports, 8 FMMU, 4 SM, 4 KiB, 64-bit DC.
    "LAN9252": EscProfile("LAN9252", 0xC0, 0x01, 0x0001, 8, 4, 4,
                          (_MII, _MII, _NONE, _NONE),
                          int(Feature.DC_SUPPORTED | Feature.DC_64BIT
                              | Feature.ENHANCED_LINK_MII | Feature.SEPARATE_FCS_ERRORS
                              | Feature.ENHANCED_DC_SYNC), sii_read_bytes=4),
    # An FPGA IP core configured generously: 4 MII ports, 8 FMMU, 8 SM, 60 KiB.
    "IPCORE": EscProfile("IPCORE", 0x04, 0x03, 0x0301, 8, 8, 60,
                         (_MII, _MII, _MII, _MII),
                         int(Feature.DC_SUPPORTED | Feature.DC_64BIT
                             | Feature.ENHANCED_LINK_MII | Feature.SEPARATE_FCS_ERRORS
                             | Feature.ENHANCED_DC_SYNC)),
}


def profile(name: str) -> EscProfile:
    """Look up a profile by name (case-insensitive)."""
    key = name.upper()
    try:
        return PROFILES[key]
    except KeyError:
        from pyethercat.errors import ConfigError
        raise ConfigError(f"unknown ESC profile {name!r}: choose one of {', '.join(PROFILES)}") from None
