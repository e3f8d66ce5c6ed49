"""What reading a campaign back proves about it, and what it cannot.

``load_campaign(path, check_data=True)`` (``eskin info --check``) reads every recording's data
and validates every label and attribute. Only what a checksum covers is proved unchanged: a
gzip-compressed chunk carries zlib's Adler-32 of its samples (checked as it is decompressed),
and a dataset written with HDF5's Fletcher-32 filter carries its own. An uncompressed chunk, the
labels and the attributes carry none in an eskin campaign (docs/dataset-format.md): a flipped
bit that leaves a label in its range (a modality id 0 read as 1) cannot be detected.
:func:`check_report` says which is which for one file.
"""

from __future__ import annotations

import os
from typing import Any

__all__ = ["check_report"]

_DEFLATE, _FLETCHER32 = 1, 3


def _filters(ds: Any) -> set[int]:
    plist = ds.id.get_create_plist()
    return {int(plist.get_filter(i)[0]) for i in range(plist.get_nfilters())}


def _data_line(n: int, filters: set[int]) -> str:
    sums = []
    if _DEFLATE in filters:
        sums.append("gzip's Adler-32")
    if _FLETCHER32 in filters:
        sums.append("HDF5's Fletcher-32")
    if not sums:
        return (f"check: read the data of all {n} recordings; it is stored uncompressed, with no "
                f"checksum: an unreadable chunk would have been found, a changed sample cannot be")
    return (f"check: read the data of all {n} recordings; every chunk matched its checksum "
            f"({' and '.join(sums)})")


def check_report(path: str | os.PathLike[str]) -> list[str]:
    """The lines saying what a data check of the campaign file ``path`` (already loaded with
    ``check_data=True``) verified: the recordings' data against the checksums it carries, the
    labels within their ranges, and which labels, extra fields and attributes carry a checksum
    (in an eskin campaign, none)."""
    import h5py

    with h5py.File(path, "r") as f:
        grp = f["recordings"]
        lines = [_data_line(int(grp["signals"].shape[0]), _filters(grp["signals"]))]
        labels = sorted(k for k in grp if k != "signals" and isinstance(grp[k], h5py.Dataset))
        extra = grp.get("extra")
        extras = [f"extra/{k}" for k in (extra or {}) if isinstance(extra[k], h5py.Dataset)]
        summed = [k for k in labels + extras if _FLETCHER32 in _filters(grp[k])]
    lines.append(f"check: the labels ({', '.join(labels)}) are within their ranges")
    bare = [k for k in labels + extras if k not in summed]
    if summed:
        lines.append(f"check: {', '.join(summed)} matched their checksums (HDF5's Fletcher-32)")
    lines.append(f"check: {_unsummed(labels, extras, bare)} carry no checksum: a changed "
                 f"value that stays in range (a modality id 0 read as 1) cannot be detected")
    return lines


def _unsummed(labels: list[str], extras: list[str], bare: list[str]) -> str:
    """'the labels, the extra fields and the attributes', naming the fields when only some
    carry no checksum."""
    parts = []
    for group, name in ((labels, "the labels"), (extras, "the extra fields")):
        without = [k for k in group if k in bare]
        if without:
            parts.append(name if without == group else ", ".join(without))
    return " and ".join([", ".join(parts), "the attributes"]) if parts else "the attributes"
