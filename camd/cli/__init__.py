"""Command-line entry points: ``camd`` (server side) and ``camctl`` (client)."""
