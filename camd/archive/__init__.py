"""``camd archive``: a camd data directory served through Tiled (docs/archive.md).

``describe`` says what the archive shows of one file (its node's path, its searchable metadata,
its arrays), read through camd's own readers; ``catalogue`` puts that into Tiled's catalogue
(SQLite by default, PostgreSQL alike) and keeps it current with the directory; ``server`` runs
Tiled's server over it with its single-user key; ``command`` is the subcommand. Tiled is an
optional dependency (``camd[archive]``), imported only when a command runs.
"""
