"""The one exception type the command line turns into a one-line error and exit status 2."""


class InputError(Exception):
    """Bad input from the user or the outside world (files, devices, pipes, serial lines).

    The message must be one line that says what is wrong and where; the CLI prints
    `occloc: <message>` and exits non-zero without a traceback.
    """
