"""Files and the run store: safe file names and writes (files), HDF5 run files (store),
checkpoints (checkpoint) and when a run writes them (schedules).

Sits above the case schema (``capsim.config``); never imports a run, a campaign or the CLI.
One public surface: ``capsim.storage.<name>`` for every name of
``__all__`` (``TrajectoryWriter``, ``open_run``, ``read_trajectory``, ``read_run_record``, ``FileLock``,
``checkpoint_path`` ...), each loaded from its module on first access; ``import capsim.storage`` loads
no h5py. The library's own modules import each other by their full name.
"""

from capsim._surface import lazy_surface

#: module -> the names it gives the package's surface
_SURFACE = {
    "files": ("FileLock StorageError OutputError LockedError check_writable guard_output protected "
              "replace_atomically write_durably write_failure starts_with is_hdf5 is_run_file is_study_file "
              "is_summary_file ladder_work_path remove_stale_ladder_files CAMPAIGN_FILE INDEX_FILE FIGURE_MAGIC"),
    "store": ("TrajectoryWriter TrajectoryError open_run read_trajectory read_run_record read_run_status "
              "read_run_digest read_run_identity read_case read_end_state case_from_trajectory guard_run_output "
              "mark_abandoned move_run write_accuracy write_error_estimate REQUESTED_CASE"),
    "checkpoint": ("checkpoint_path read_checkpoint load_end_state remove_checkpoint without_t_end first_difference "
                   "CheckpointError ResumeError"),
    "schedules": "SnapshotSchedule CheckpointSchedule end_tolerance",
}
__all__, __getattr__, __dir__ = lazy_surface(__name__, _SURFACE)
