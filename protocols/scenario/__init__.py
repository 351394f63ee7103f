"""Scenario files: the typed file model and its loading, the field schema, the generator behind
``swarm scenario new`` with its templates and layouts."""
