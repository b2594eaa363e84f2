"""LZFSE decompression that checks the declared output size before decompressing.

The ``lzfse`` package decompresses whatever it is given into a buffer it grows as needed, so a
small crafted ``.depth`` entry could expand to gigabytes. An LZFSE stream is a sequence of blocks
whose headers state how many raw bytes each block produces; this module walks those headers
(format as in Apple's reference ``lzfse_internal.h``) and refuses streams whose total differs
from the size the caller expects, before any decompression happens.
"""

from __future__ import annotations

import struct

import lzfse

_END = b"bvx$"
_RAW = b"bvx-"
_LZVN = b"bvxn"
_V2 = b"bvx2"
_V1 = b"bvx1"
# Size of lzfse_compressed_block_header_v1 in the reference implementation (packed fields + the
# four frequency tables of uint16: 20 + 20 + 64 + 256 entries).
_V1_HEADER = 4 * 7 + 4 + 8 + 4 + 6 + 2 * (20 + 20 + 64 + 256)


def declared_raw_size(data: bytes) -> int:
    """Total decompressed size in bytes that an LZFSE stream's block headers declare.

    Raises ``ValueError`` when the stream's block structure is malformed (unknown block magic,
    a block running past the end, no end-of-stream marker).
    """
    pos, total, n = 0, 0, len(data)
    while True:
        if pos + 4 > n:
            raise ValueError(f"stream ends at byte {pos} without an end-of-stream block")
        magic = data[pos : pos + 4]
        if magic == _END:
            return total
        if pos + 8 > n:
            raise ValueError(f"block header at byte {pos} is truncated")
        (raw,) = struct.unpack_from("<I", data, pos + 4)
        if magic == _RAW:
            length = 8 + raw
        elif magic == _LZVN:
            if pos + 12 > n:
                raise ValueError(f"LZVN block header at byte {pos} is truncated")
            (payload,) = struct.unpack_from("<I", data, pos + 8)
            length = 12 + payload
        elif magic == _V2:
            if pos + 32 > n:
                raise ValueError(f"LZFSE block header at byte {pos} is truncated")
            v0, v1, v2 = struct.unpack_from("<3Q", data, pos + 8)
            literal_payload = (v0 >> 20) & 0xFFFFF
            lmd_payload = (v1 >> 40) & 0xFFFFF
            header_size = v2 & 0xFFFFFFFF
            if header_size < 32:
                raise ValueError(f"LZFSE block at byte {pos} declares a header of {header_size} bytes")
            length = header_size + literal_payload + lmd_payload
        elif magic == _V1:
            if pos + 28 > n:
                raise ValueError(f"LZFSE v1 block header at byte {pos} is truncated")
            lit, lmd = struct.unpack_from("<II", data, pos + 20)
            length = _V1_HEADER + lit + lmd
        else:
            raise ValueError(f"unknown block type {magic!r} at byte {pos}")
        total += raw
        pos += length
        if pos > n:
            raise ValueError("a block runs past the end of the data")


def safe_decompress(data: bytes, expected_bytes: int) -> bytes:
    """Decompress LZFSE ``data`` that must expand to exactly ``expected_bytes`` bytes.

    Raises ``ValueError`` (with the reason) when the declared size differs, the stream is
    malformed, or the decompressed size differs from the declaration.
    """
    declared = declared_raw_size(data)
    if declared != expected_bytes:
        raise ValueError(f"declares {declared} decompressed bytes, expected {expected_bytes}")
    try:
        out = lzfse.decompress(data)
    except lzfse.error as exc:
        raise ValueError(f"LZFSE data is corrupt ({exc})") from exc
    if len(out) != expected_bytes:
        raise ValueError(f"decompressed to {len(out)} bytes, expected {expected_bytes}")
    return out
