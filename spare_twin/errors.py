"""The one exception type the library raises for bad input; the CLI prints it on one line."""


class SpareTwinError(Exception):
    """A user-facing error: the CLI prints its message on one line and exits non-zero.

    Library functions name the parameter or file at fault, never a command-line flag; the commands
    translate parameter names to their flags (`spare_twin.commands.common`)."""
