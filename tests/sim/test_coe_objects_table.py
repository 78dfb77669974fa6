"""The simulator's CoE dictionaries built from the standard-object table hold plain numbers."""

from __future__ import annotations

from pyethercat.sim.devices.coe_io import add_seed002_objects, coe_io_dictionary
from pyethercat.sim.od import SimObjectDictionary
from pyethercat.wire.mailbox.objects import StandardObject, SyncSub


def _all_plain(od: SimObjectDictionary) -> bool:
    return all(type(o.index) is int and all(type(e.subindex) is int for e in o.entries.values())
               for o in od)


def test_coe_io_dictionary_uses_the_table() -> None:
    od = coe_io_dictionary(0x1, 0x2, 0x3)
    assert _all_plain(od)  # enum members are stored as numbers (repr, sorting, JSON)
    indices = [o.index for o in od]
    assert indices == sorted(indices)
    for obj in (StandardObject.IDENTITY, StandardObject.SM_COMM_TYPE,
                StandardObject.RXPDO_ASSIGNMENT, StandardObject.TXPDO_ASSIGNMENT,
                StandardObject.SM_OUTPUT_SYNC, StandardObject.SM_INPUT_SYNC):
        assert obj in od and int(obj) in od
    assert od.value(0x1C32, SyncSub.SYNC_MODE) == 1
    assert od.value(0x1C33, SyncSub.SYNC_MODE) == 0x22
    assert od.value(0x1C32, SyncSub.SYNC_MODES_SUPPORTED) == 0x0007
    assert [od.value(0x1C00, s) for s in range(5)] == [4, 1, 2, 3, 4]
    assert od.get(0x1C12).name == "RxPDO assign" and od.get(0x1C13).name == "TxPDO assign"
    assert od.get(0x1C10).name == "SM0 PDO assign" and od.get(0x1C11).name == "SM1 PDO assign"


def test_seed002_objects_use_the_table() -> None:
    od = SimObjectDictionary()
    add_seed002_objects(od)
    assert _all_plain(od)
    assert [o.index for o in od] == [0x1000, 0x1001, 0x1018, 0x1100,
                                     0x1600, 0x1601, 0x1602, 0x1603,
                                     0x1A00, 0x1A01, 0x1A02, 0x1A03,
                                     0x1C00, 0x1C10, 0x1C11, 0x1C12, 0x1C13,
                                     0x6040, 0x6041, 0x6060, 0x6061]
    assert [od.value(0x1C12, s) for s in range(1, 5)] == [0x1600, 0x1601, 0x1602, 0x1603]
