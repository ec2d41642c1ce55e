from collections.abc import Callable
from typing import Any

class HotStep:
    def __init__(
        self,
        wrapper: Any,
        clock: Any,
        env_step: Callable[[Any], Any],
        ring: list[Any] | None,
        act: Callable[[Any], Any],
        observe: Callable[[Any, int], Any],
        template: dict[str, Any],
        shape: tuple[int, ...],
        dtype: Any,
        randomizer: Any,
        corruptor: Any,
        phys: Any,
        signals: Any,
        merged: Any,
        step_end: Callable[..., Any],
        diverged: Callable[[], Any] | None,
        asarray: Callable[..., Any],
        wrong_shape: Callable[[tuple[int, ...], tuple[int, ...]], str],
    ) -> None: ...
    def __call__(self, action: Any, /) -> tuple[Any, Any, bool, bool, dict[str, Any]]: ...
