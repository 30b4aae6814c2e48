from typing import Any

def configure(
    classes: tuple[type[Any], type[Any], type[Any]],
    fields: dict[str, int],
    limits: dict[str, float],
) -> None: ...
def step(plan: tuple[Any, ...], records: tuple[Any, ...], now: float) -> Any: ...
def linear_wire(
    terms: tuple[int, int, int, int, bool] | None, fields: tuple[int, ...]
) -> int | None: ...
