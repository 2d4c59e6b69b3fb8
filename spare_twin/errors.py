"""The one exception type the library raises for bad input; the CLI prints it on one line."""


class SpareTwinError(Exception):
    """A user-facing error: the CLI prints its message on one line and exits non-zero.

    Library functions name the parameter or file at fault, never a command-line flag; the commands
    translate parameter names to their flags (`spare_twin.commands.common`)."""


def first_line(exc: BaseException) -> str:
    """The first line of an exception's message (its type's name when it has none): what a one-line
    error quotes of a library's error."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__
