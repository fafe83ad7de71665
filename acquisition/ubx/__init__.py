"""u-blox UBX binary protocol: the frame (sync, class, id, length, payload, Fletcher checksum),
the timing messages UBX-TIM-TM2 (event marks) and UBX-TIM-TP (the next time pulse) declared as
binary layouts, and a stream decoder for UBX interleaved with NMEA on one port.

- `frame`: the frame, its checksum, and a stream framer's verdict on bytes;
- `messages`: the messages as data, their encoder and decoder, messages from GPS instants;
- `stream`: the framer, and the NMEA + UBX stream decoder.
"""

from acquisition.ubx.frame import (
    MAX_PAYLOAD_BYTES,
    UbxRefusal,
    encode_frame,
    first_ubx_frame,
    fletcher8,
)
from acquisition.ubx.messages import (
    TIM_TM2,
    TIM_TP,
    UBX_SPECS,
    TimeBase,
    TimTm2,
    TimTp,
    UbxMessage,
    UbxName,
    UnknownUbx,
    decode_ubx,
    encode_ubx,
    tim_tm2_from_gps_ns,
    tim_tp_for_pulse,
    ubx_name,
)
from acquisition.ubx.stream import GpsMessage, NmeaUbxStreamDecoder, UbxFramer

__all__ = [
    "MAX_PAYLOAD_BYTES", "TIM_TM2", "TIM_TP", "UBX_SPECS", "GpsMessage", "NmeaUbxStreamDecoder",
    "TimTm2", "TimTp", "TimeBase", "UbxFramer", "UbxMessage", "UbxName", "UbxRefusal",
    "UnknownUbx", "decode_ubx", "encode_frame", "encode_ubx", "first_ubx_frame", "fletcher8",
    "tim_tm2_from_gps_ns", "tim_tp_for_pulse", "ubx_name",
]
