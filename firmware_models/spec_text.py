"""The ``key=value,key=value`` text of the simulator's specs (``--inject``, ``--scene``)."""

from __future__ import annotations


def key_values(
    text: str, *, what: str, example: str, keys_note: str, error: type[ValueError]
) -> list[tuple[str, str]]:
    """The ``(key, raw value)`` items of ``text``, in order; blank items are skipped.

    Raises ``error`` for an item that is not ``key=value`` (saying ``what`` it is for, with
    ``example`` and ``keys_note``) and for a key given twice. Keys and values are stripped; the
    caller checks the keys and converts the values.
    """
    items: list[tuple[str, str]] = []
    seen: set[str] = set()
    for item in text.split(","):
        item = item.strip()
        if not item:
            continue
        key, eq, raw = item.partition("=")
        key, raw = key.strip(), raw.strip()
        if not eq or not key:
            raise error(
                f"{what} item {item!r} is not key=value; write e.g. '{example}' ({keys_note})"
            )
        if key in seen:
            raise error(f"{what} key {key!r} is given twice; give it once")
        seen.add(key)
        items.append((key, raw))
    return items
