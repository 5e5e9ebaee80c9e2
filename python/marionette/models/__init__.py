"""Robot, object and scene models: their generator and the YAML declarations (grippers,
handles, tags, contact surfaces).

``marionette.robots`` is the entry point for users (paths, Pinocchio loading, reference
postures); :mod:`marionette.models.semantics` parses the YAML; the other modules generate
``models/`` (scripts/generate_models.py).
"""
