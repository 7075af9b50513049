"""What the config files have in common: the data files of config/ (camera, stage and wheel
profiles, register maps, the command dictionary), camd.toml and the campaigns.

``Sourced`` holds a physical value with its provenance (a paper's section, or why it was
assumed); ``DataFileKind`` reads every kind of TOML data file the one way (parse, validate,
check; shipped files found by name); ``DataFileError`` is a file that does not validate, its
message starting with ``file:line:``; ``located`` turns a pydantic ValidationError (or a
``KeyedError`` a check raised) into that message, with the line of the key in the TOML text.
``problem`` words each of pydantic's errors, the same fault in the same words in every config
file: ``located`` and ``every_error`` (camd.toml, all its errors at once) with it, and the
campaign files (YAML, camd.campaign.explain), which begin their errors the same way (``place``)
with the lines ``yaml_lines`` finds. Pure: the simulated camera reads the same files.
"""

from __future__ import annotations

from camd.datafile.loading import DataFileKind, parse_toml, read_toml
from camd.datafile.places import (
    DataFileError,
    KeyedError,
    Loc,
    line_of,
    place,
    yaml_line,
    yaml_lines,
    yaml_problem,
)
from camd.datafile.quoting import ERROR_MESSAGE_MAX, SHOWN_MAX, WORD_MAX, bounded, cut, what_it_is
from camd.datafile.sourced import Count, NonNegative, Positive, Sourced, physical, unit_of
from camd.datafile.words import every_error, located, problem, wrong_type

__all__ = [
    "ERROR_MESSAGE_MAX",
    "SHOWN_MAX",
    "WORD_MAX",
    "Count",
    "DataFileError",
    "DataFileKind",
    "KeyedError",
    "Loc",
    "NonNegative",
    "Positive",
    "Sourced",
    "bounded",
    "cut",
    "every_error",
    "line_of",
    "located",
    "parse_toml",
    "physical",
    "place",
    "problem",
    "read_toml",
    "unit_of",
    "what_it_is",
    "wrong_type",
    "yaml_line",
    "yaml_lines",
    "yaml_problem",
]
