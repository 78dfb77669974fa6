"""Error acknowledge on slaves in device emulation against the simulator.

A chip without firmware (EK1100, EL2004: ESC configuration 0x0141 bit 0, from
SII word 0) copies AL control bits 4:0 into AL status, acknowledge bit
included: after ``state | ACK`` it shows the error flag until the state is
written once more without it. Firmware slaves must get the acknowledge alone.
"""

from __future__ import annotations

import shutil
import struct
from pathlib import Path

import pytest

from pyethercat.clock import VirtualClock
from pyethercat.link.pair import PairLink
from pyethercat.master.master import Master
from pyethercat.wire import registers as reg
from pyethercat.wire.al import AlState, AlStatusCode
from pyethercat.wire.datagram import Command
from pyethercat.wire.frame import decode_frame


class Recorder:
    """Passes frames to the segment and records every AL control write by station."""

    def __init__(self, process: object) -> None:
        self.process = process
        self.al_control: list[tuple[int, int]] = []

    def __call__(self, frame: bytes) -> object:
        for d in decode_frame(frame).datagrams:
            if d.command == Command.FPWR and d.ado == reg.AL_CONTROL:
                self.al_control.append((d.adp, struct.unpack_from("<H", d.data)[0]))
        return self.process(frame)  # type: ignore[operator]


@pytest.fixture
def sim(corpus_dir: Path, tmp_path: Path) -> tuple[object, Master, Recorder]:
    from pyethercat.sim.topology import load_topology

    shutil.copy(corpus_dir / "sii" / "ethercrab_el2004.bin", tmp_path / "el2004.bin")
    path = tmp_path / "t.toml"
    path.write_text('[[slave]]\nname = "el2004"\nsii = "el2004.bin"\n'
                    '[[slave]]\nname = "fw"\ndevice = "builtin:coe-io"\n')
    seg = load_topology(path).build()
    rec = Recorder(seg.process)
    m = Master(PairLink.responder_link(rec), clock=VirtualClock())
    m.scan()
    m.set_state("PREOP")
    return seg, m, rec


def test_device_emulation_is_known_from_the_sii(sim: tuple[object, Master, Recorder]) -> None:
    seg, m, _ = sim
    assert m.slaves[0].device_emulation is True
    assert m.slaves[1].device_emulation is False
    # The same bit the chip loaded into 0x0141.
    for slave in m.slaves:
        esc_config = m.read(slave, reg.ESC_CONFIG, 1)[0]
        assert bool(esc_config & reg.EscConfig.DEVICE_EMULATION) == slave.device_emulation


def test_device_emulation_is_known_without_the_sii(sim: tuple[object, Master, Recorder]) -> None:
    """The scan reads 0x0141 itself, so a scan without SII (ENI start) knows it too."""
    seg, _, _ = sim
    m = Master(PairLink.responder_link(seg.process), clock=VirtualClock())  # type: ignore[attr-defined]
    m.scan(read_sii=False)
    assert [s.sii for s in m.slaves] == [None, None]
    assert [s.esc_config is not None for s in m.slaves] == [True, True]
    assert [s.device_emulation for s in m.slaves] == [True, False]


def test_acknowledge_clears_the_flag_on_emulation_and_firmware_slaves(
    sim: tuple[object, Master, Recorder],
) -> None:
    seg, m, rec = sim
    el, fw = m.slaves
    # An error the ESC or the firmware set, with a code.
    seg.slave(0).esc.set_al_error(AlStatusCode.SM_WATCHDOG)  # type: ignore[attr-defined]
    seg.slave(1).esc.set_al_error(AlStatusCode.SM_WATCHDOG)  # type: ignore[attr-defined]
    m.read_states()
    assert el.al_error and fw.al_error
    rec.al_control.clear()
    assert m.acknowledge_errors() == [el, fw]
    m.read_states()
    assert not el.al_error and el.al_state == AlState.PREOP and el.al_status_code == 0
    assert not fw.al_error and fw.al_state == AlState.PREOP
    ack = int(AlState.PREOP) | reg.AL_ERROR_FLAG
    # The emulation slave gets the ack and then the plain state; the firmware slave
    # the ack only (its firmware could see a request without ack while in error).
    assert [v for a, v in rec.al_control if a == el.station_address] == [ack, int(AlState.PREOP)]
    assert [v for a, v in rec.al_control if a == fw.station_address] == [ack]


def test_acknowledge_of_an_echoed_ack_bit(sim: tuple[object, Master, Recorder]) -> None:
    # Someone wrote state | ACK to the emulation slave: the copy shows the flag
    # with code 0. acknowledge_errors must leave it without the flag.
    _seg, m, _ = sim
    el = m.slaves[0]
    m.write(el, reg.AL_CONTROL, struct.pack("<H", int(AlState.PREOP) | reg.AL_ERROR_FLAG))
    m.read_states()
    assert el.al_error and el.al_status_code == 0
    assert m.acknowledge_errors() == [el]
    m.read_states()
    assert not el.al_error and el.al_state == AlState.PREOP
    assert m.acknowledge_errors() == []


def test_set_state_on_flagged_slaves_ends_without_flags(
    sim: tuple[object, Master, Recorder],
) -> None:
    seg, m, rec = sim
    seg.slave(0).esc.set_al_error(AlStatusCode.SM_WATCHDOG)  # type: ignore[attr-defined]
    seg.slave(1).esc.set_al_error(AlStatusCode.SM_WATCHDOG)  # type: ignore[attr-defined]
    m.set_state("PREOP")
    m.read_states()
    assert [(s.al_state, s.al_error) for s in m.slaves] == [(AlState.PREOP, False)] * 2
    m.set_state("INIT")
    assert [(s.al_state, s.al_error) for s in m.slaves] == [(AlState.INIT, False)] * 2
