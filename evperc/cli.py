"""Command line: click commands only. Parse, call the library, report; no maths here.

Every :class:`~evperc.errors.EvpercError` becomes one line on stderr and exit code 2.
"""

from __future__ import annotations

import functools
import logging
import sys
from collections.abc import Callable
from typing import Any

import click

from evperc import __version__
from evperc.errors import EvpercError

log = logging.getLogger("evperc")


def _setup_logging(verbose: int, quiet: int) -> None:
    level = logging.INFO - 10 * verbose + 10 * quiet
    logging.basicConfig(level=max(logging.DEBUG, min(logging.CRITICAL, level)),
                        format="%(levelname)s: %(message)s", stream=sys.stderr, force=True)


def user_errors(func: Callable[..., Any]) -> Callable[..., Any]:
    """Turn user errors into ``evperc: error: <message>`` and exit code 2; Ctrl-C into exit 130."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except EvpercError as err:
            click.echo(f"evperc: error: {err}", err=True)
            sys.exit(err.exit_code)
        except KeyboardInterrupt:
            click.echo("evperc: interrupted", err=True)
            sys.exit(130)

    return wrapper


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="evperc")
@click.option("-v", "--verbose", count=True, help="More log output (repeatable).")
@click.option("-q", "--quiet", count=True, help="Less log output (repeatable).")
def cli(verbose: int, quiet: int) -> None:
    """Map-aided evidential occupancy grids from logged drives (Kurdej et al. 2013)."""
    _setup_logging(verbose, quiet)


def main() -> None:
    """Console-script entry point."""
    cli(prog_name="evperc")


if __name__ == "__main__":  # pragma: no cover
    main()
