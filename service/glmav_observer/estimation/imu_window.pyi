from collections.abc import Sequence

Vec3 = tuple[float, float, float]

class PairWindow:
    t_last_s: float
    def __len__(self) -> int: ...
    def note(self, t_s: float, f_body_mps2: Vec3) -> None: ...
    @property
    def baseline(self) -> list[float] | None: ...
    @property
    def f_last(self) -> Vec3: ...
    def step(
        self,
        t_s: float,
        f_body_mps2: Vec3,
        window_s: float,
        max_age_s: float,
        min_samples: int,
        min_fill: float,
    ) -> tuple[list[float], list[float]] | None: ...
    def learn_baseline(self, dev: Sequence[float], tau_s: float) -> None: ...
    def onset(self, floor_mps2: float) -> float: ...

def deviation_test(
    devs: Sequence[tuple[Sequence[float], Sequence[float]]],
    floor_mps2: float,
    k_sigma: float,
    end_fraction: float,
) -> tuple[list[float], bool, bool, list[float]]: ...
