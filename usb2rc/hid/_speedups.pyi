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

def pull(
    reader: object, device: object, now: float, limit: int, kept: int, bad_limit: int
) -> bool | None: ...
def parse_events(lines: Sequence[str]) -> tuple[list[float], list[bytes]] | None: ...
def parse_packed(text: str) -> tuple[Events, int, int] | None: ...

class Events:
    def __len__(self) -> int: ...
    def schedule(self, start: float, speed: float, floor: float) -> float: ...
    def take(self, now: float, limit: int) -> list[bytes]: ...
    def pairs(self) -> tuple[list[float], list[bytes]]: ...
    @property
    def next_due(self) -> float: ...
    @property
    def last_time(self) -> float: ...
    @property
    def left(self) -> int: ...

class ReaderCounts:
    reports: int
    bad_reports: int
    refused_in_a_row: int
    bad_spells: int
    repeats: int
    press_serial: int
    last_report: bytes
    presses: tuple[int, ...]
    closed: bool
    pull_error: BaseException | None

class DecoderState:
    values: list[int]
    buttons: int
    state: object
    reports: int
    bad_reports: int
