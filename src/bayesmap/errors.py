"""Errors raised by bayesmap for bad user input."""


class BayesmapError(ValueError):
    """Bad input from a user: a message that names the offending value. The CLI prints it on one line and exits 2."""
