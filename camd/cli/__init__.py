"""Command-line entry points, the user's commands: ``camd`` (server side) and ``camctl`` (client).

The tools that measure camd rather than run a camera, ``camd bench`` and ``camd soak``, live in
``camd.bench`` and ``camd.soak``; ``camd_main`` imports them only when their command runs.
"""
