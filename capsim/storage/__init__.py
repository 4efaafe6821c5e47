"""Files and the run store: safe file names and writes (files), HDF5 run files (store),
checkpoints (checkpoint) and when a run writes them (schedules).

Sits above the case schema (``capsim.config``); never imports a run, a campaign or the CLI.
Modules are imported by their full name; this ``__init__`` loads nothing (no h5py on import).
"""
