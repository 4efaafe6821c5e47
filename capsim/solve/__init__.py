"""One step after another: the boundary-integral model of a scene (solver), the time schemes and
their cost model, the observables measured along a run, and the error model behind
``time.rtol: auto`` and accuracy targets (``error_model.json``).

Imports the numerics and the scene; never the schema's users above it (run files, runs,
campaigns, the CLI). Modules are imported by their full name; this ``__init__`` loads nothing.
"""
