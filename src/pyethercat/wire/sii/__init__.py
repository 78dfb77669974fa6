"""SII (slave information interface, EEPROM) codec shared by master, simulator and ESI tools.

- ``parse_sii(data, strict=False) -> SiiInfo``: bytes -> typed model (tolerant
  by default, problems in ``info.warnings``; strict raises ``SiiError``).
- ``build_sii(info) -> bytes``: typed model -> full image with a correct CRC,
  end marker and 0xFF padding to the EEPROM size.
- ``sii_crc(first_14_bytes)``, ``sii_fix_checksum(image)``: header checksum.
- ``sii_bytes_needed(read_so_far)``: how far the master must read (pure).
- ``format_sii(info)``: readable multi-line dump.
"""

from pyethercat.wire.sii.codec import (
    SII_DEFAULT_MAX_BYTES,
    build_sii,
    category_body,
    parse_sii,
    sii_bytes_needed,
    sii_crc,
    sii_fix_checksum,
)
from pyethercat.wire.sii.format import format_sii
from pyethercat.wire.sii.model import (
    SM_NOT_ASSIGNED,
    CategoryType,
    CoeDetails,
    FmmuUsage,
    GeneralFlags,
    MailboxProtocol,
    SiiCategory,
    SiiDc,
    SiiDcMode,
    SiiFmmus,
    SiiGeneral,
    SiiInfo,
    SiiPdo,
    SiiPdoEntry,
    SiiPdoFlags,
    SiiPdos,
    SiiPortType,
    SiiRawCategory,
    SiiStrings,
    SiiSyncManager,
    SiiSyncManagers,
    SyncManagerEnable,
    SyncManagerType,
    category_name,
)

# The image is one object: ``SiiImage`` is the name some callers expect.
SiiImage = SiiInfo

__all__ = [
    "SII_DEFAULT_MAX_BYTES",
    "SM_NOT_ASSIGNED",
    "CategoryType",
    "CoeDetails",
    "FmmuUsage",
    "GeneralFlags",
    "MailboxProtocol",
    "SiiCategory",
    "SiiDc",
    "SiiDcMode",
    "SiiFmmus",
    "SiiGeneral",
    "SiiImage",
    "SiiInfo",
    "SiiPdo",
    "SiiPdoEntry",
    "SiiPdoFlags",
    "SiiPdos",
    "SiiPortType",
    "SiiRawCategory",
    "SiiStrings",
    "SiiSyncManager",
    "SiiSyncManagers",
    "SyncManagerEnable",
    "SyncManagerType",
    "build_sii",
    "category_body",
    "category_name",
    "format_sii",
    "parse_sii",
    "sii_bytes_needed",
    "sii_crc",
    "sii_fix_checksum",
]
