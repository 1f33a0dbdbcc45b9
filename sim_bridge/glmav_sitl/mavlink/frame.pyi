"""Type stub of the compiled frame.pyx."""

def frame_v2(
    payload: bytes, msgid: int, crc_extra: int, seq: int, sysid: int, compid: int
) -> bytes: ...
