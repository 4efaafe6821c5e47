"""Many runs: campaigns (sweeps) and their executor (processes, dask), the summary of a campaign,
and convergence studies.

Imports runs, the run store and below; never the CLI or plots. Modules are imported by their
full name; this ``__init__`` loads nothing.
"""
