"""What every command shares: translating library parameter names into the command's flags."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from spare_twin.errors import SpareTwinError


@contextmanager
def flags(**param_to_flag: str) -> Iterator[None]:
    """Library errors name the parameter at fault ("seed -1: ..."); say it as the user typed it ("--seed -1: ...")."""
    try:
        yield
    except SpareTwinError as exc:
        message = str(exc)
        for param, flag in param_to_flag.items():
            if message.startswith((f"{param} ", f"{param}:")):
                raise SpareTwinError(flag + message[len(param) :]) from None
        raise
