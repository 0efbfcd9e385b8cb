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


INCLUSIONS_HELP = ("spheres of other material in the forward model: JSON or a YAML/JSON file, a list of "
                   "{center_m: [x, y, z], radius_m: r, scale: {C1: f, C2: f} or 'fitted'}; 'fitted' scales C1 "
                   "and C2 by inc_scale of a law with +inclusion (e.g. elastic+inclusion)")


def inclusions_arg(text):
    """The --inclusions option's spheres; UserError on bad input."""
    from ..forward import read_inclusions
    try:
        return read_inclusions(text)
    except (ValueError, KeyError, TypeError) as e:
        raise UserError(f"--inclusions: {e}") from None
    except Exception as e:          # YAML syntax
        raise UserError(f"--inclusions: cannot read {text!r} ({e})") from None
