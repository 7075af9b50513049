"""The NeXus structure of camd's HDF5 files: the data, the detector and every setting, for
tools that know NeXus (nexusformat, silx, h5web) and nothing of camd.

camd's scan and recording files are NeXus files (NeXus: the NIAC's HDF5 conventions for
scientific data). Everything a measurement is lives in one entry::

    /                      NXroot, default="entry", file_time, creator, creator_version
    /entry                 NXentry, default="data": title, start_time, end_time (at the
                           close, or by the repair of a file whose writer died), program_name
    /entry/data            NXdata: signal="lines" (or "frames", units "counts",
                           interpretation "image"), axes, <axis>_indices; the per-line
                           (per-frame) axis is the file's own column, the column (and row)
                           axes pixel indices
    /entry/instrument      NXinstrument: name (the camera profile)
    /entry/instrument/detector
                           NXdetector: description, local_name, x_pixel_size, y_pixel_size,
                           bit_depth_readout, frame_time, count_time (SI ``units``)
    /entry/instrument/detector/tdi
                           NXcollection: camd's TDI settings, which NXdetector has no field
                           for (mode, stages, window_rows)
    /entry/instrument/detector/per_line (per_frame)
                           NXcollection: every other per-line (per-frame) dataset of the file
                           and its flushed count
    /entry/instrument/stage
                           NXpositioner: the scan stage; raw_value is each line's (frame's)
                           encoder count, value the position in m when the file knows the
                           encoder's counts per metre, velocity the stage speed (m/s)
    /entry/sample          NXsample: the scene or target in front of the camera, if known
    /entry/campaign_step   NXnote: the campaign step that made the file (its control
                           activity), if any
    /entry/camd            NXcollection: the root's camd attributes (format, format_version,
                           finished, ...) as fields, written when the file is closed or
                           repaired (when they have their final values)
    /entry/<group>         each metadata group of the file (profile, registers, timing, scan,
                           stream, counters, motion, ...): NXparameters for the settings a run
                           is made with (timing, scan, stream, motion), NXcollection for the
                           rest; each value a field, with ``units`` from its name's suffix
                           (``_s`` -> s, ``_m`` -> m, ``_hz`` -> Hz, ...: ``units_of``); a
                           profile's described value (``{"value", "source"}``) the field of
                           its value, the rest its attributes; another nested mapping a
                           nested NXcollection

The datasets are stored once: each exists under its root name (``/lines``, ``/frames``, the
columns, the flushed count, camd's layout since format 1) and inside the entry, as HDF5 hard
links: the same dataset under two names, which grows with the file while it is written (SWMR).
The metadata groups and the root attributes stay where camd's readers, the repair and the
older camd versions look for them (their attributes); the entry holds their values again as
fields, written when the file is made and brought up to date when it is closed or repaired
(``finish_nexus``). A NeXus validator (nexusformat's ``nxcheck``) finds nothing to act on in
the entry: what it still reports is camd's layout at the root (the root's datasets, which
NXroot does not define, and its attributes), outside any entry, where NeXus readers do not look.
Everything in the entry but ``end_time``, ``camd`` and the close's values (counters, motion,
the stage's position in m) is made when the file is created, before it goes to SWMR mode (whose
writer may not add objects): a recording's settings when it is opened, its data and detector
with the first frame (which gives their shape).
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import h5py
import numpy as np
import numpy.typing as npt

__all__ = [
    "ENTRY",
    "ENTRY_NAMES",
    "ROOT_NEXUS_ATTRS",
    "Axis",
    "camera_name",
    "finish_nexus",
    "sensor_fields",
    "units_of",
    "write_nexus",
    "write_settings",
]

ENTRY = "entry"  # the NeXus entry's group: reserved, never a metadata group
# The root attributes NeXus defines that camd writes (the rest of the root's are camd's).
ROOT_NEXUS_ATTRS = ("NX_class", "default", "file_time", "creator", "creator_version")
CAMD = "camd"  # the entry's collection of the root's camd attributes
CAMPAIGN_STEP = "campaign_step"
# What the entry holds besides the metadata groups: no metadata group may take these names.
ENTRY_NAMES = frozenset(
    {
        "data",
        "instrument",
        CAMD,
        CAMPAIGN_STEP,
        "title",
        "start_time",
        "end_time",
        "program_name",
    }
)
# Metadata groups holding the settings a run is made with: NXparameters when every value is a
# plain field (NXparameters holds no groups); every other group is an NXcollection.
PARAMETER_GROUPS = frozenset({"timing", "scan", "stream", "motion"})
# The metadata group whose ``text`` names the campaign step (``camd.daemon``: the control
# activity the campaign runner sets), written as the NXnote ``campaign_step``; and the one
# naming the scene or target in front of the camera, written as the NXsample ``sample``.
ACTIVITY_GROUP = "activity"
SAMPLE_GROUP = "sample"
# Units of a value from its name's suffix (camd names carry their unit), longest first.
# ``_over_v``: a ratio (M dV/V), no volts.
_SUFFIX_UNITS: tuple[tuple[str, str], ...] = (
    ("_over_v", ""),
    ("_uv_per_e", "uV/electron"),
    ("_e_per_s", "electron/s"),
    ("_mbyte_per_s", "MB/s"),
    ("_mpix_per_s", "Mpixel/s"),
    ("_deg_s", "deg/s"),
    ("_m_s2", "m/s^2"),
    ("_m_s", "m/s"),
    ("_degc", "degC"),
    ("_khz", "kHz"),
    ("_mhz", "MHz"),
    ("_hz", "Hz"),
    ("_ns", "ns"),
    ("_us", "us"),
    ("_ms", "ms"),
    ("_s", "s"),
    ("_nm", "nm"),
    ("_um", "um"),
    ("_mm", "mm"),
    ("_m", "m"),
    ("_deg", "deg"),
    ("_rad", "rad"),
    ("_v", "V"),
    ("_w", "W"),
    ("_db", "dB"),
    ("_dn", "counts"),
    ("_e", "electron"),
)
# Groups whose names carry no units: register names are the camera's, their values codes.
_NO_UNITS = frozenset({"registers"})
_WHOLE_NAME_UNITS = {"mbyte_per_s": "MB/s", "mpix_per_s": "Mpixel/s"}


def units_of(name: str) -> str:
    """The units of a camd value named ``name`` from its suffix (``exposure_s`` -> "s",
    ``pitch_m`` -> "m", ``pixel_rate_hz`` -> "Hz"); "" for a name without one."""
    lowered = name.lower()
    if lowered in _WHOLE_NAME_UNITS:
        return _WHOLE_NAME_UNITS[lowered]
    for suffix, units in _SUFFIX_UNITS:
        if lowered.endswith(suffix) and len(lowered) > len(suffix):
            return units
    return ""


@dataclass(frozen=True)
class Axis:
    """One axis of the signal: ``link`` names a root dataset to link (a per-line or per-frame
    column), or ``values`` are stored (pixel indices); ``units`` as NeXus writes them."""

    name: str
    link: str | None = None
    values: npt.ArrayLike | None = None
    units: str = ""
    long_name: str = ""


def profile_value(profile: Mapping[str, Any], key: str) -> Any:
    """A camera profile's value as recordings store it (``{"value": v, "source": ...}`` or
    ``v``); None if absent."""
    entry = profile.get(key)
    if isinstance(entry, Mapping):
        return entry.get("value")
    return entry


def camera_name(profile: Mapping[str, Any]) -> str:
    """The camera a file's profile metadata names (its profile, else its sensor)."""
    return str(profile.get("profile") or profile.get("sensor") or "camera")


def sensor_fields(profile: Mapping[str, Any]) -> dict[str, tuple[Any, str]]:
    """The NXdetector fields a camera profile gives: description, sensor, pixel pitch."""
    pitch_m = profile_value(profile, "pitch_m")
    return {
        "description": (profile.get("description"), ""),
        "local_name": (profile.get("sensor"), ""),
        "x_pixel_size": (pitch_m, "m"),
        "y_pixel_size": (pitch_m, "m"),
    }


def _group(parent: h5py.Group, name: str, nx_class: str) -> h5py.Group:
    """``parent``'s group ``name`` of ``nx_class``, made if missing."""
    group = parent.require_group(name)
    group.attrs["NX_class"] = nx_class
    return group


def _stored(value: Any) -> Any:
    """A metadata value as HDF5 stores it: numpy's fixed-width text has no HDF5 type
    (variable-length UTF-8 instead); lists as arrays."""
    if isinstance(value, (list, tuple)):
        value = np.asarray(value) if value else np.zeros(0)
    if isinstance(value, np.ndarray) and value.dtype.kind == "U":
        return np.asarray(value.tolist(), dtype=h5py.string_dtype())
    return value


def _put(group: h5py.Group, name: str, value: Any, units: str = "") -> None:
    """The field ``name`` of ``group`` set to ``value``: written over in place if it has the
    same shape and type, else replaced."""
    value = _stored(value)
    old = group.get(name)
    if old is not None:
        if (
            isinstance(old, h5py.Dataset)
            and old.shape == np.shape(value)
            and _same_type(old, value)
        ):
            old[()] = value
        else:
            del group[name]
            old = None
    if old is None:
        group[name] = value
    if units:
        group[name].attrs["units"] = units


def _same_type(dataset: h5py.Dataset, value: Any) -> bool:
    """Whether ``value`` can be written over ``dataset``'s as it is: text over text, else the
    same numpy type."""
    if isinstance(value, (str, bytes)):
        return h5py.check_string_dtype(dataset.dtype) is not None
    return bool(dataset.dtype == np.asarray(value).dtype)


def _link(group: h5py.Group, name: str, target: h5py.Dataset) -> None:
    """``target`` also under ``group``'s ``name`` (a hard link: the same dataset)."""
    if name not in group:
        group[name] = target


def _is_flat(values: Mapping[str, Any]) -> bool:
    return not any(isinstance(v, Mapping) for v in values.values())


def _write_values(group: h5py.Group, values: Mapping[str, Any], *, with_units: bool = True) -> None:
    """Each value of ``values`` a field of ``group`` with the units of its name (none unless
    ``with_units``); a described value (``{"value": v, "source": ...}``, a camera profile's)
    the field ``v`` with the rest as its attributes; any other mapping a nested NXcollection;
    None left out."""
    for key, value in values.items():
        if value is None:
            continue
        name = key.replace("/", "_")  # a field's name, not a path into the file
        units = units_of(name) if with_units else ""
        if isinstance(value, Mapping):
            if "value" in value and _is_flat(value):
                _put(group, name, value["value"], units)
                for what, about in value.items():
                    if what != "value" and about is not None:
                        group[name].attrs[what] = _stored(about)
                continue
            _write_values(_group(group, name, "NXcollection"), value, with_units=with_units)
            continue
        _put(group, name, value, units)


def write_settings(f: h5py.File, groups: Mapping[str, Mapping[str, Any]]) -> None:
    """The entry's copy of the metadata ``groups`` (each root group's name and the values it
    was given, nested, as its writer has them: not read back from the file, which costs a
    millisecond an attribute on a busy host) as fields with units, merged into what the entry
    has; the root groups' datasets linked; the sample, the campaign step and the stage's known
    settings. Made when the file is (the entry too), brought up to date when it is closed."""
    entry = _group(f, ENTRY, "NXentry")
    for name, values in groups.items():
        if name in (ENTRY, ACTIVITY_GROUP, SAMPLE_GROUP) or name in ENTRY_NAMES:
            continue  # the sample and the campaign step have their own NeXus classes
        have = entry.get(name)
        was = have.attrs.get("NX_class") if isinstance(have, h5py.Group) else None
        flat = _is_flat(values) and was != "NXcollection"
        nx_class = "NXparameters" if name in PARAMETER_GROUPS and flat else "NXcollection"
        _write_values(_group(entry, name, nx_class), values, with_units=name not in _NO_UNITS)
    for name, node in f.items():
        if not isinstance(node, h5py.Group) or name == ENTRY or not len(node):
            continue
        for child, dataset in node.items():
            if isinstance(dataset, h5py.Dataset):
                # A group with datasets (motion_loop, background) is a record, no parameter set.
                _link(_group(entry, name, "NXcollection"), child, dataset)
                units = units_of(child)
                if units and "units" not in dataset.attrs:
                    dataset.attrs["units"] = units
    _write_sample(f)
    _write_campaign_step(f)
    _write_stage_settings(f)


def _attrs(f: h5py.File, group: str) -> Mapping[str, Any]:
    node = f.get(group)
    return node.attrs if isinstance(node, h5py.Group) else {}


def _text(value: Any) -> str:
    return value.decode() if isinstance(value, bytes) else str(value)


def _write_sample(f: h5py.File) -> None:
    """NXsample: the scene (simulated camera) or target named in the scan's or the stream's
    settings."""
    for group in (SAMPLE_GROUP, "scan", "stream"):
        attrs = _attrs(f, group)
        for key in ("target", "scene"):
            if key in attrs:
                sample = _group(f[ENTRY], SAMPLE_GROUP, "NXsample")
                _put(sample, "name", _text(attrs[key]))
                what = "the simulated camera's scene" if key == "scene" else "the target"
                _put(sample, "description", f"{what} in front of the camera ({group}.{key})")
                return


def _write_campaign_step(f: h5py.File) -> None:
    """NXnote: the campaign step (the control activity) that made the file, if it says."""
    attrs = _attrs(f, ACTIVITY_GROUP)
    if "text" not in attrs:
        return
    note = _group(f[ENTRY], CAMPAIGN_STEP, "NXnote")
    _put(note, "type", "text/plain")
    _put(note, "description", _text(attrs["text"]))
    if "set_utc" in attrs:
        _put(note, "date", _text(attrs["set_utc"]))
    if "done" in attrs:
        _put(note, "sequence_index", int(attrs["done"]) + 1)


def _write_stage_settings(f: h5py.File) -> None:
    """The stage's speed and, with the encoder's counts per metre, its position in m."""
    stage = f.get(f"{ENTRY}/instrument/stage")
    if stage is None:
        return
    for group in ("motion", "timing"):
        speed = _attrs(f, group).get("stage_speed_m_s")
        if speed is not None:
            _put(stage, "velocity", float(speed), "m/s")
            break
    for group in ("motion", "scan"):
        per_m = _attrs(f, group).get("encoder_counts_per_m")
        if per_m is not None and float(per_m) > 0 and "raw_value" in stage:
            position_m = np.asarray(stage["raw_value"][()], dtype=np.float64) / float(per_m)
            _put(stage, "value", position_m, "m")
            stage["value"].attrs["long_name"] = "stage position at each line's frame start"
            break


def write_nexus(
    f: h5py.File,
    *,
    title: str,
    start_time: str,
    program: str,
    instrument: str,
    detector: Mapping[str, tuple[Any, str]],
    signal: str,
    axes: Sequence[Axis],
    tdi: Mapping[str, Any] | None = None,
    per_element: tuple[str, Sequence[str]] = ("per_frame", ()),
    stage: str | None = None,
) -> None:
    """Add the NeXus entry (module docstring) to ``f``, whose root holds ``signal``, the
    linked axes and the datasets named in ``per_element`` (the collection's name, the root
    datasets it links). ``detector`` maps NXdetector field names to (value, units); a None
    value is left out. The axes are in the signal's dimension order. ``tdi``: the TDI
    settings (None values left out); ``stage``: the root dataset of the stage's encoder counts.
    The metadata groups are the writer's to copy (``write_settings``), before or after."""
    f.attrs.update(
        {
            "NX_class": "NXroot",
            "default": ENTRY,
            "file_time": start_time,
            "creator": "camd",
            "creator_version": program.removeprefix("camd "),
        }
    )
    entry = _group(f, ENTRY, "NXentry")
    entry.attrs["default"] = "data"
    _put(entry, "title", title)
    _put(entry, "start_time", start_time)
    _put(entry, "program_name", program)
    inst = _group(entry, "instrument", "NXinstrument")
    _put(inst, "name", instrument)
    det = _group(inst, "detector", "NXdetector")
    for name, (value, units) in detector.items():
        if value is not None:
            _put(det, name, value, units)
    settings = {name: value for name, value in (tdi or {}).items() if value is not None}
    if settings:
        _write_values(_group(det, "tdi", "NXcollection"), settings)
    data = _group(entry, "data", "NXdata")
    data.attrs["signal"] = signal
    data.attrs["axes"] = [axis.name for axis in axes]
    _link(data, signal, f[signal])
    node = data[signal]
    node.attrs.update({"units": "counts", "long_name": f"{signal} (DN)"})
    if len(axes) >= 2:
        node.attrs["interpretation"] = "image"
    for index, axis in enumerate(axes):
        if axis.link is not None:
            _link(data, axis.name, f[axis.link])
        else:
            data.create_dataset(axis.name, data=np.asarray(axis.values))
        node = data[axis.name]
        if axis.units and "units" not in node.attrs:
            node.attrs["units"] = axis.units
        if axis.long_name and "long_name" not in node.attrs:
            node.attrs["long_name"] = axis.long_name
        data.attrs[f"{axis.name}_indices"] = index
    collection, names = per_element
    columns = _group(det, collection, "NXcollection")
    for name in names:
        if name in f:
            _link(columns, name, f[name])
            units = units_of(name)
            if units and "units" not in f[name].attrs:
                f[name].attrs["units"] = units
    if stage is not None and stage in f:
        positioner = _group(inst, "stage", "NXpositioner")
        _put(positioner, "name", "scan stage")
        _put(positioner, "description", "the scan stage carrying the target, along the scan")
        _link(positioner, "raw_value", f[stage])
        raw = positioner["raw_value"]
        if "units" not in raw.attrs:
            raw.attrs["units"] = "counts"
            raw.attrs["long_name"] = "encoder count at each line's (frame's) start"


def _write_camd(f: h5py.File) -> None:
    """The root's camd attributes as fields of the entry's ``camd`` NXcollection."""
    camd = _group(f[ENTRY], CAMD, "NXcollection")
    for name, value in f.attrs.items():
        if name in ROOT_NEXUS_ATTRS:
            continue
        _put(camd, name, value, units_of(name))


def finish_nexus(
    f: h5py.File,
    groups: Mapping[str, Mapping[str, Any]] | None = None,
    end_time: str | None = None,
) -> None:
    """Bring a closed (or repaired) file's entry up to date: ``end_time`` (default now, UTC),
    the root's camd attributes, the metadata ``groups`` the close added to (``write_settings``;
    none for a repair: a dead writer changed none). Nothing for a file without an entry (a
    format before NeXus)."""
    if ENTRY not in f:
        return
    stamp = end_time or dt.datetime.now(dt.UTC).isoformat(timespec="milliseconds")
    _put(f[ENTRY], "end_time", stamp)
    _write_camd(f)
    write_settings(f, groups or {})
