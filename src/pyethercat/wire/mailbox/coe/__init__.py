"""CoE (CANopen over EtherCAT) codecs: CoE header, SDO, SDO information, emergency.

Every message class has ``encode()`` returning the mailbox *payload* (CoE
header included, mailbox header excluded); :func:`decode_coe` is the inverse.
Wrap a payload with :func:`pyethercat.wire.mailbox.header.encode_mailbox`.

Modules by concern: :mod:`.header` (CoE header, services, SDO abort codes),
:mod:`.sdo` (SDO messages), :mod:`.emergency` (emergency, PDO over the
mailbox), :mod:`.info` (SDO information service and its fragments),
:mod:`.decode` (any payload to its message), :mod:`.transfer` (the SDO
transfer state machines, clients and servers, in the h11 manner). Everything
is importable from this package.
"""

from __future__ import annotations

from pyethercat.wire.mailbox.coe.decode import CoeMessage, decode_coe
from pyethercat.wire.mailbox.coe.emergency import (
    EMERGENCY_ERROR_CLASSES,
    CoePdo,
    Emergency,
    ErrorRegister,
    emergency_error_name,
)
from pyethercat.wire.mailbox.coe.header import (
    COE_HEADER_SIZE,
    SDO_ABORT_CODES,
    SDO_HEADER_SIZE,
    CoeHeader,
    CoeService,
    SdoAbortCode,
    sdo_abort_name,
)
from pyethercat.wire.mailbox.coe.info import (
    ObjectAccess,
    ObjectCode,
    OdListType,
    SdoInfoError,
    SdoInfoFragment,
    SdoInfoGetEntryDescriptionRequest,
    SdoInfoGetEntryDescriptionResponse,
    SdoInfoGetObjectDescriptionRequest,
    SdoInfoGetObjectDescriptionResponse,
    SdoInfoGetOdListRequest,
    SdoInfoGetOdListResponse,
    SdoInfoMessage,
    SdoInfoOpCode,
    SdoInfoReassembler,
    ValueInfo,
    decode_sdo_info_body,
    encode_sdo_info_fragments,
)
from pyethercat.wire.mailbox.coe.sdo import (
    SdoAbortTransfer,
    SdoDownloadSegmentRequest,
    SdoDownloadSegmentResponse,
    SdoInitiateDownloadRequest,
    SdoInitiateDownloadResponse,
    SdoInitiateUploadRequest,
    SdoInitiateUploadResponse,
    SdoUploadSegmentRequest,
    SdoUploadSegmentResponse,
)
from pyethercat.wire.mailbox.coe.transfer import (
    SdoDownloadClient,
    SdoDownloadEvent,
    SdoDownloadServer,
    SdoTransferDone,
    SdoUploadClient,
    SdoUploadServer,
    sdo_initiate_max_data,
    sdo_segment_max_data,
)
from pyethercat.wire.mailbox.datatypes import (
    DATA_TYPE_BITS,
    TYPE_NAMES,
    DataType,
    Value,
    decode_value,
    encode_value,
    format_value,
    parse_type_name,
    parse_value,
)

__all__ = [
    # header
    "COE_HEADER_SIZE",
    "SDO_HEADER_SIZE",
    "CoeService",
    "CoeHeader",
    # aborts
    "SdoAbortCode",
    "SDO_ABORT_CODES",
    "sdo_abort_name",
    # SDO messages
    "SdoInitiateDownloadRequest",
    "SdoInitiateDownloadResponse",
    "SdoDownloadSegmentRequest",
    "SdoDownloadSegmentResponse",
    "SdoInitiateUploadRequest",
    "SdoInitiateUploadResponse",
    "SdoUploadSegmentRequest",
    "SdoUploadSegmentResponse",
    "SdoAbortTransfer",
    "CoePdo",
    "Emergency",
    "EMERGENCY_ERROR_CLASSES",
    "emergency_error_name",
    "ErrorRegister",
    # SDO information
    "SdoInfoOpCode",
    "OdListType",
    "ObjectCode",
    "ValueInfo",
    "ObjectAccess",
    "SdoInfoGetOdListRequest",
    "SdoInfoGetOdListResponse",
    "SdoInfoGetObjectDescriptionRequest",
    "SdoInfoGetObjectDescriptionResponse",
    "SdoInfoGetEntryDescriptionRequest",
    "SdoInfoGetEntryDescriptionResponse",
    "SdoInfoError",
    "SdoInfoFragment",
    "SdoInfoReassembler",
    "encode_sdo_info_fragments",
    "decode_sdo_info_body",
    # decode
    "CoeMessage",
    "SdoInfoMessage",
    "decode_coe",
    # transfers
    "sdo_initiate_max_data",
    "sdo_segment_max_data",
    "SdoTransferDone",
    "SdoUploadClient",
    "SdoDownloadClient",
    "SdoUploadServer",
    "SdoDownloadServer",
    "SdoDownloadEvent",
    # data types (re-exported from datatypes)
    "DataType",
    "DATA_TYPE_BITS",
    "TYPE_NAMES",
    "Value",
    "encode_value",
    "decode_value",
    "parse_type_name",
    "parse_value",
    "format_value",
]
