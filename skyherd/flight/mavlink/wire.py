"""The MAVLink 2 frame's fixed layout, shared by every encoder and decoder here (the endpoint's
codec, the simulator bridge's hand-built HIL frames): start bytes, header, checksum.

A frame is STX, the 9 header bytes below, the payload (trailing zeros dropped), the X.25 CRC
of header + payload + CRC_EXTRA, and a 13-byte signature when incompat bit 0x01 is set.
"""

from __future__ import annotations

import struct

from fastcrc import crc16

STX_V2 = 0xFD
STX_V1 = 0xFE
HDR_V2 = struct.Struct("<BBBBBBBHB")  # stx len incompat compat seq sys comp msgid(lo16, hi8)
CRC = struct.Struct("<H")
X25 = crc16.mcrf4xx  # the X.25 checksum (CRC-16/MCRF4XX): X25(data, X25(more)) chains, as pymavlink
