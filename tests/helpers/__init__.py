"""Shared test helpers, one module per part of the package they serve (``tests.helpers.<part>``)."""
