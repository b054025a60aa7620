"""Runnable examples; a package so that the tests import them by name."""
