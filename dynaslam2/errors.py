"""User-facing errors: bad input that the CLI reports as one clear line and a non-zero exit."""


class InputError(Exception):
    """Invalid user input (a file, a parameter, a value). The message names what and what was expected."""


class ConfigError(InputError):
    """An unknown or invalid configuration key or value."""
