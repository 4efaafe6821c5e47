"""What a person sees: the command line (cli, cli_errors), the terminal display, figures (plot)
and exports to other tools (export).

The top layer with ``capsim.api``: nothing below imports it. Modules are imported by their full
name; this ``__init__`` loads nothing, so ``capsim --help`` stays fast.
"""
