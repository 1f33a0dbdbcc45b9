from collections import deque

Vec3 = tuple[float, float, float]

def mean_and_sigma(
    window: deque[tuple[float, Vec3]],
) -> tuple[list[float], list[float], int]: ...
