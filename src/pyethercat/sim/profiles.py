"""ESC profiles: chip families with their resources.

A profile says what a slave controller has: identity register values, how
many FMMUs and sync managers, how much process RAM, which ports, which
features. The ESC model derives from it which register bytes exist (reads
and writes of bytes a chip lacks are answered with working counter 0) and
which bytes the EtherCAT side may write.

Values follow the public descriptions of the chips (Beckhoff ET1100/ET1200,
Microchip LAN9252, an FPGA IP core); where a value was not found in a public
source it is a plausible default and can be overridden per device with
:meth:`EscProfile.replace`.

Board profiles (``EK1100``, ``EL1004``, ``EL2828``, ``EL2889``, ``AKD``) are a chip
family with the values the real devices read in the corpus captures
(../shared/corpus): identity registers, port descriptor, features, which DC
registers exist, SII control quirks. ``DEVICE_PROFILES`` maps SII identities
to them, so a slave built from such a device's SII dump behaves like it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from pyethercat.wire.registers import EscFeaturesMixin, Feature, PortType, port_descriptor

__all__ = [
    "DEVICE_PROFILES",
    "PROFILES",
    "EscProfile",
    "profile",
]

# Real EK1100 and EL2889 (corpus captures) read 0x0008 = 0x00FC (EL2828, EL1004: 0x01FC).
_DC_FULL = (Feature.DC_SUPPORTED | Feature.DC_64BIT | Feature.LOW_JITTER_EBUS
            | Feature.ENHANCED_LINK_EBUS | Feature.ENHANCED_LINK_MII
            | Feature.SEPARATE_FCS_ERRORS)


@dataclass(frozen=True)
class EscProfile(EscFeaturesMixin):
    """Resources and identity of one ESC family.

    ``ports`` gives the type of ports 0-3 (``PortType.NOT_IMPLEMENTED`` for a
    port the chip does not have). ``sii_read_bytes`` is 4 or 8: how many bytes
    one SII read command fetches (0x0502 bit 6 reports 8). ``forwarding_delay_ns``
    is the delay a frame needs to pass the chip once (None: from the port
    types: see :attr:`default_forwarding_delay_ns`).
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
    #: Undocumented bits of SII control 0x0502 some chips show while the
    #: slave is below SAFEOP (INIT, PREOP, BOOT): the EL1004 and EL2828 of the
    #: corpus read 0x0050 idle there (bit 4), the EL1004 0x0040 in SAFEOP.
    sii_control_static: int = 0
    #: False: the DC unit has the port receive-time latches 0x0900-0x090F
    #: only, no system time, offset, delay or cyclic unit (0x0910-0x09FF are
    #: not implemented: reads, writes and FRMW there are not counted). Real
    #: EL2828, EL1004, EL3004 and EK1914 answer 0x0900 but not 0x0910 though
    #: 0x0008 says "DC supported"; the features register does not tell.
    dc_system_time: bool = True
    #: Power-on content of the receive-time latches 0x0900-0x090F; a port
    #: that never saw a latching frame keeps it (Beckhoff ASICs read "hoff"
    #: at port 1 and "Verl" at port 3, SOEM slaveinfo and ethercrab captures).
    dc_receive_time_reset: bytes = bytes(16)
    #: ESC family ("ET1100", "ET1200", ...) of a board profile; "" = the
    #: profile is the family itself.
    family: str = ""
    #: EEPROM timing of the board (0: commands complete at once). A read or
    #: reload keeps SII control busy (bit 15, with the command bits) for
    #: ``sii_read_ns``, a write for ``sii_write_ns``; after a write the EEPROM
    #: runs its internal write cycle until ``sii_write_cycle_ns`` after the
    #: command and does not acknowledge commands meanwhile (bit 13 set, the
    #: command is not carried out). ``Segment.sii_busy_ns`` overrides the busy times.
    sii_read_ns: int = 0
    sii_write_ns: int = 0
    sii_write_cycle_ns: int = 0
    #: The PDI emulates the EEPROM (SII control 0x0502 bit 5 set; ESC
    #: datasheet section II, 0x0502): the device's firmware answers the SII
    #: commands, at once as far as the master sees.
    sii_emulated: bool = False
    #: PDI control and ESC configuration (0x0140-0x0141) fixed by the chip's
    #: own configuration (an FPGA IP core) instead of SII word 0; None: from the SII.
    pdi_control: int | None = None

    def replace(self, **changes: object) -> EscProfile:
        """A copy with some fields changed (e.g. ports of a particular board)."""
        return dataclasses.replace(self, **changes)  # type: ignore[arg-type]

    @property
    def port_descriptor(self) -> int:
        """Value of register 0x0007 (two bits per port)."""
        return port_descriptor(self.ports)

    @property
    def implemented_ports(self) -> tuple[int, ...]:
        """Port numbers the chip has."""
        return tuple(n for n, p in enumerate(self.ports) if p.implemented)

    @property
    def ram_end(self) -> int:
        """First address after the process RAM."""
        return min(0x1000 + self.ram_kib * 1024, 0x10000)

    @property
    def default_forwarding_delay_ns(self) -> int:
        """Forwarding delay through this chip (explicit, else from the port types)."""
        if self.forwarding_delay_ns is not None:
            return self.forwarding_delay_ns
        if any(p == PortType.MII for p in self.ports):
            # MII ports go through PHYs: ethercrab measured 720 ns (oscilloscope
            # 725 ns) from one LAN9252 board to the next (``NOTES.md``).
            return 700
        # E-Bus terminals: the EL2828/EL2889 of the corpus captures measure
        # 310 ns across the link between them (two passes and two E-Bus links).
        return 150


_MII, _EBUS, _NONE = PortType.MII, PortType.EBUS, PortType.NOT_IMPLEMENTED

# Receive-time latches of Beckhoff ASICs before any latching frame passed a
# port: port 1 reads "hoff", port 3 "Verl" (port 0 always latches; port 2 reads 0).
_BECKHOFF_LATCH_RESET = bytes(4) + b"hoff" + bytes(4) + b"Verl"
_NOT_CONFIGURED = PortType.NOT_CONFIGURED
# ET1200 terminals of the corpus read features 0x01FC (bit 8 enhanced DC SYNC).
_DC_FULL_SYNC = int(_DC_FULL | Feature.ENHANCED_DC_SYNC)
# EEPROM timing of the Beckhoff boards, fitted on the captures
# replay-ek1100-el2828-el2889 and replay-ek1100-alias-address (master time
# stamps): an 8-byte read is busy for 675.6-711.4 us (EK1100), 620.6-792.8 us
# (EL2828), 630.8-774.2 us (EL2889); a one-word write for 296.8-297.5 us;
# after a write, commands 2.95 ms later were not acknowledged (0x0502 bit 13)
# and 3.67 ms later accepted (alias-address). Held out: replay-dc,
# replay-issue-255, soem-sdinfo-ek1100-only, and for the EL1004 (no capture of
# its own fitted) soem-sdinfo-ek1100-el1004, 541-773 us
# (tests/sim/test_replay_corpus.py checks that 690 us lies in the busy window
# each of them shows).
_EE_READ, _EE_WRITE, _EE_CYCLE = 690_000, 297_000, 3_300_000
# The generic chips answer SII commands at once. Their datasheets give the
# EEPROM times (ET1100 section III table 79, ET1200 table 47: ~680 us for a
# 4-word read, ~250 us for a write at the ~150 kHz EEPROM clock), but a
# master running in-process on a virtual clock of its own sees busy for as
# many frames as that time holds (a hundred polls per read, a scan minutes
# long); the board profiles below keep their measured timing.

PROFILES: dict[str, EscProfile] = {
    # Beckhoff ET1100: 4 ports, 8 FMMU, 8 SM, 8 KiB, 64-bit DC (EK1100 uses
    # MII on port 0 and 3 and E-Bus on 1; port 2 unused by the coupler).
    "ET1100": EscProfile("ET1100", 0x11, 0x00, 0x0002, 8, 8, 8,
                         (_MII, _EBUS, _EBUS, _MII), int(_DC_FULL)),
    # Beckhoff ET1200: 3 ports (E-Bus terminals use 0 and 1), 3 FMMU, 4 SM, 1 KiB.
    "ET1200": EscProfile("ET1200", 0x12, 0x00, 0x0001, 3, 4, 1,
                         (_EBUS, _EBUS, _NONE, _NONE), int(_DC_FULL)),
    # Microchip LAN9252: 2 MII ports, 3 FMMU, 4 SM, 4 KiB DPRAM (its data
    # sheet's highlights), 64-bit DC.
    "LAN9252": EscProfile("LAN9252", 0xC0, 0x01, 0x0001, 3, 4, 4,
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
    # --- boards: chip family + what the real devices of the corpus read -----
    # EK1100 (twincat-scan-boxes, soem-sdinfo-*): 0x0000-0x0009 =
    # 11 00 0003 08 08 08 3B 00FC: ET1100 rev 0 build 3, ports 0 MII, 1 E-Bus,
    # 2 MII, 3 not implemented; full 64-bit DC.
    # Forwarding 125 ns: its port-1 round trip to the EL2828 + EL2889 reads
    # 590-600 ns in the replay captures (310 of them behind the EL2828).
    "EK1100": EscProfile("EK1100", 0x11, 0x00, 0x0003, 8, 8, 8,
                         (_MII, _EBUS, _MII, _NONE), int(_DC_FULL), forwarding_delay_ns=125,
                         dc_receive_time_reset=_BECKHOFF_LATCH_RESET, family="ET1100",
                         sii_read_ns=_EE_READ, sii_write_ns=_EE_WRITE,
                         sii_write_cycle_ns=_EE_CYCLE),
    # EL1004 (twincat-scan-boxes, soem-sdinfo-ek1100-el1004): type 0x12 rev 1
    # build 1, ports 0x4A (E-Bus 0/1, port 2 absent, port 3 not configured),
    # features 0x01FC, DC receive times only, SII control 0x0050 below SAFEOP.
    "EL1004": EscProfile("EL1004", 0x12, 0x01, 0x0001, 3, 4, 1,
                         (_EBUS, _EBUS, _NONE, _NOT_CONFIGURED), _DC_FULL_SYNC,
                         sii_control_static=0x0010, dc_system_time=False,
                         dc_receive_time_reset=_BECKHOFF_LATCH_RESET, family="ET1200",
                         sii_read_ns=_EE_READ, sii_write_ns=_EE_WRITE,
                         sii_write_cycle_ns=_EE_CYCLE),
    # EL2828 (replay-* captures): 3 FMMUs, 4 SMs (BWR 0x0600-0x083F working
    # counters), features 0x01FC, no system time (0x0910.. not counted, 0x0918
    # read with WKC 0), SII control 0x0050 idle, DL status PDI watchdog bit 1.
    # Type/revision/build are not read singly in the captures (BRD 0x0000 of
    # the three slaves ORs to 0x13): taken from the EL1004's ET1200.
    "EL2828": EscProfile("EL2828", 0x12, 0x01, 0x0001, 3, 4, 1,
                         (_EBUS, _EBUS, _NONE, _NOT_CONFIGURED), _DC_FULL_SYNC,
                         sii_control_static=0x0010, dc_system_time=False,
                         dc_receive_time_reset=_BECKHOFF_LATCH_RESET, family="ET1200",
                         sii_read_ns=_EE_READ, sii_write_ns=_EE_WRITE,
                         sii_write_cycle_ns=_EE_CYCLE),
    # EL2889 (replay-* captures): 3 FMMUs, 4 SMs, features 0x00FC, full DC
    # (system time, offset, delay, 0x092C), SII control 0x0040 idle.
    "EL2889": EscProfile("EL2889", 0x12, 0x01, 0x0001, 3, 4, 1,
                         (_EBUS, _EBUS, _NONE, _NOT_CONFIGURED), int(_DC_FULL),
                         dc_receive_time_reset=_BECKHOFF_LATCH_RESET, family="ET1200",
                         sii_read_ns=_EE_READ, sii_write_ns=_EE_WRITE,
                         sii_write_cycle_ns=_EE_CYCLE),
    # Kollmorgen AKD servo drive, an EtherCAT IP core in its FPGA. Read off
    # soem-sdinfo-akd: type 0x04 rev 0x02 (BRD 0x0000), port descriptor 0x0F
    # (ports 0 and 1 MII), features 0x0184 (DC with 32-bit system time:
    # 0x0918 reads 0 in its upper half; separate FCS error counters,
    # enhanced DC SYNC), PDI control 0x0C08 (16-bit asynchronous
    # microcontroller; DC SYNC out and latch in units) although the SII's word
    # 0 says 0x0009, SII control 0x0020 (EEPROM emulated by the firmware,
    # 4-byte reads, never busy when polled 560 us after a command), port 1
    # receive time "hoff" before it latched, ports 2 and 3 0. Not read there
    # and taken from twincat-akd-nc-mode (APRD 0x0000, 10 bytes): build
    # 0x0043, 3 FMMUs, 4 SMs, 4 KiB RAM. twincat-akd-nc-mode checks the
    # rest: it reads type, revision, port descriptor and features as above,
    # and SII control 0x0020.
    "AKD": EscProfile("AKD", 0x04, 0x02, 0x0043, 3, 4, 4,
                      (_MII, _MII, _NONE, _NONE),
                      int(Feature.DC_SUPPORTED | Feature.SEPARATE_FCS_ERRORS | Feature.ENHANCED_DC_SYNC),
                      sii_read_bytes=4, family="IPCORE", sii_emulated=True, pdi_control=0x0C08,
                      dc_receive_time_reset=bytes(4) + b"hoff" + bytes(8)),
}

#: Profiles of known devices, by SII identity (vendor, product code): a slave
#: built from an SII dump without an explicit ``profile`` gets this one.
DEVICE_PROFILES: dict[tuple[int, int], str] = {
    (0x0000_0002, 0x044C_2C52): "EK1100",
    (0x0000_0002, 0x03EC_3052): "EL1004",
    (0x0000_0002, 0x0B0C_3052): "EL2828",
    (0x0000_0002, 0x0B49_3052): "EL2889",
    (0x0000_006A, 0x0041_4B44): "AKD",
}


def profile(name: str) -> EscProfile:
    """Look up a profile by name (case-insensitive)."""
    key = name.upper()
    try:
        return PROFILES[key]
    except KeyError:
        from pyethercat.errors import ConfigError
        raise ConfigError(f"unknown ESC profile {name!r}: choose one of {', '.join(PROFILES)}") from None
