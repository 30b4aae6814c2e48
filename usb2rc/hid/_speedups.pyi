from collections.abc import Sequence

class Plan:
    def __init__(
        self,
        uses_ids: bool,
        reports: Sequence[
            tuple[
                int,
                int,
                int,
                Sequence[tuple[int, int, int, bool]],
                Sequence[tuple[int, int, int, int]],
            ]
        ],
    ) -> None: ...
    def drain(
        self, batch: list[bytes], values: list[int], mask: int, edges: bool
    ) -> tuple[int, int, int, list[int]]: ...

def parse_events(lines: Sequence[str]) -> tuple[list[float], list[bytes]] | None: ...
def parse_block(text: str) -> tuple[list[float], list[bytes], int, int] | None: ...
def running_dues(times: list[float], start: float, speed: float, floor: float) -> list[float]: ...
