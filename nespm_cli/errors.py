"""The one exception type the CLI turns into a one-line message and exit code 2."""


class NespmError(Exception):
    """Bad input or option: the message is one line naming the file, row or option."""

    exit_code = 2
