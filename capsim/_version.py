"""capsim's version: the installed package's, else the source tree's (one place for every module)."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("capsim")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.1.0"
