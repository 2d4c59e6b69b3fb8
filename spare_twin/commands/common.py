"""What every command shares: translating library parameter names into the command's flags."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from spare_twin.errors import SpareTwinError


@contextmanager
def flags(**param_to_flag: str) -> Iterator[None]:
    """Library errors name the parameter at fault ("seed -1: ..."); say it as the user typed it ("--seed -1: ...").

    A message that starts with a parameter name (then a space or a colon) gets the flag in its place;
    an output the output rule refuses names the flag that forces it: `force`'s flag, "--force" unless
    the command names another."""
    try:
        yield
    except SpareTwinError as exc:
        # spare_twin.output pulls in numpy (through io): imported only when there is an error to say
        from spare_twin.output import OutputRefused

        if isinstance(exc, OutputRefused):
            raise SpareTwinError(exc.message(param_to_flag.get("force", "--force"))) from None
        message = str(exc)
        for param, flag in param_to_flag.items():
            if message.startswith((f"{param} ", f"{param}:")):
                raise SpareTwinError(flag + message[len(param) :]) from None
        raise
