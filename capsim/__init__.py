"""capsim: boundary-integral simulation of elastic capsules in simple shear flow."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("capsim")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.1.0"
