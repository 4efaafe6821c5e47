"""capsim's version: one place for every module and for the package's metadata (pyproject.toml reads
it as ``attr: capsim._version.__version__``). A literal, not importlib.metadata: that import costs
~30 ms at every start of a command (issue 57)."""

__version__ = "0.1.0"
