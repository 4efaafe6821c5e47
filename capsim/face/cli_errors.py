"""The command-line group's error handling: every usage error (a bad option value, an unknown
option, a missing argument), a refused resource and an exhausted memory as one line on stderr
with exit code 2, like every other user error of capsim (cli.py uses it as its group class)."""

from __future__ import annotations

import sys

import typer
from typer.core import TyperGroup

try:  # typer >= 0.2x carries its own copy of click
    from typer import _click as click
except ImportError:  # pragma: no cover - older typer on the real click
    import click


class OneLineErrors(TyperGroup):
    """Usage errors (a bad option value, an unknown option, a missing argument) as one
    line on stderr, exit 2, like every other user error of capsim."""

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        try:
            code = super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        except click.exceptions.UsageError as exc:
            if type(exc).__name__ == "NoArgsIsHelpError":  # the help was printed
                sys.exit(exc.exit_code)
            from capsim.errors import first_line

            where = exc.ctx.command_path if exc.ctx is not None else "capsim"
            text = "".join(first_line(Exception(exc.format_message()), type(exc).__name__).split("Value error, "))
            typer.echo(f"error: {text.rstrip('.')}; see '{where} -h'", err=True)
            sys.exit(2)
        except click.exceptions.ClickException as exc:
            from capsim.errors import first_line

            typer.echo(f"error: {first_line(Exception(exc.format_message()), type(exc).__name__)}", err=True)
            sys.exit(exc.exit_code)
        except typer.Abort:
            typer.echo("aborted", err=True)
            sys.exit(1)
        except OSError as exc:  # the system refused a resource (open-file limit, a path too long, ...): one line
            where = f": {exc.filename}" if getattr(exc, "filename", None) else ""
            typer.echo(f"error: {exc.strerror or type(exc).__name__}{str(where)[:300]}", err=True)
            sys.exit(2)
        except MemoryError:
            typer.echo("error: out of memory (a smaller mesh level, or fewer --workers)", err=True)
            sys.exit(2)
        sys.exit(code if isinstance(code, int) else 0)
