"""capsim: boundary-integral simulation of elastic capsules in simple shear flow."""

from capsim._version import __version__

__all__ = ["__version__", "open_run"]


def open_run(path):
    """A run file as an ``xarray.DataTree`` (one node per group); see :func:`capsim.store.open_run`."""
    from capsim.store import open_run as _open_run  # h5py and xarray only when asked for

    return _open_run(path)
