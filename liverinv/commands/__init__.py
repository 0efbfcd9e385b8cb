"""Subcommands of the `liverinv` command line."""

from ..errors import UserError


def parse_assignments(items, flag) -> dict:
    """NAME=VALUE strings of a repeatable flag -> {NAME: float(VALUE)}; UserError otherwise."""
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep:
            raise UserError(f"{flag} {item!r}: expected NAME=VALUE")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise UserError(f"{flag} {item!r}: {value!r} is not a number") from None
    return out
