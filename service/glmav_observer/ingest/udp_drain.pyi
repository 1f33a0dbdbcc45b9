"""Type stub of the compiled udp_drain.pyx."""

AVAILABLE: bool
DATAGRAM_MAX: int

class UdpDrain:
    def __init__(self, fd: int, batch: int = 64, stamps: bool = True) -> None: ...
    def drain(self, max_n: int) -> list[tuple[bytes, float, tuple[str, int] | None]]: ...
